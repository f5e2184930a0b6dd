"""`fovjax.eval.plan_fidelity`: the cheapest per-region fidelity within an added error per 5°
ring. On the spheres (mirror spheres, shadows, max_depth 2, tiny frames): a loose criterion
takes the cheapest candidate everywhere, a zero criterion keeps full fidelity (plain
foveation's frame), a middle one cheapens the outside but not the periphery, and the plan's
rings, recomputed from fresh renders, stay within the criterion. Bad arguments fail before any
rendering. Options are two-candidate chains (full, cheapest) so the whole file compiles five
programs: the full render, plain foveation and three fidelity configurations."""

from __future__ import annotations

import dataclasses

import _extras
import jax
import numpy as np
import pytest

import fovjax
from fovjax.eval import (
    DEFAULT_STEPS,
    FidelityPlan,
    HmdDisplay,
    PlanSearch,
    default_options,
    error_by_eccentricity,
    flip,
    plan_fidelity,
)
from fovjax.foveate import Fidelity, Foveation, render_foveated
from fovjax.render import RenderConfig, StereoRig, render_stereo

_extras.require("flip_evaluator", module_level=True)

CONFIG = RenderConfig(max_depth=2)  # the spheres' mirror material needs bounces
GAZES = [(0.4, 0.5)]
KEYS = [0, 1]
FULL = Fidelity()
CHEAP = Fidelity(max_depth=0, shadows="none")
CHAIN = [FULL, CHEAP]
FOVEATION = Foveation.thesis(0)


@pytest.fixture(scope="module")
def spheres():
    scene = fovjax.scenes.spheres(subdivisions=1, ground_cells=4)
    rig = StereoRig.from_pose(fovjax.scenes.default_camera(scene), eye_width=32, eye_height=24)
    return scene, rig


def _plan(spheres, threshold, options) -> FidelityPlan:
    scene, rig = spheres
    search = PlanSearch(gazes=GAZES, keys=KEYS, options=options)
    return plan_fidelity(scene, rig, FOVEATION, ("flip", threshold), search=search, config=CONFIG)


@pytest.fixture(scope="module")
def loose(spheres):
    return _plan(spheres, 1.0, CHAIN)


@pytest.fixture(scope="module")
def middle(spheres):
    # The fovea keeps full fidelity (one candidate); periphery and outside are searched.
    return _plan(spheres, 0.05, ([FULL], CHAIN, CHAIN))


def test_loose_criterion_takes_the_cheapest_option_everywhere(loose):
    assert loose.fidelity == (CHEAP, CHEAP, CHEAP)
    assert [s.region for s in loose.steps] == ["outside", "periphery", "fovea"]  # outside inward
    assert all(s.passed for s in loose.steps)
    assert loose.plan_cost["rays_per_frame"] < loose.plain_cost["rays_per_frame"]
    assert loose.plain.fidelity is None and loose.foveation.fovea_deg == FOVEATION.fovea_deg
    text = str(loose)
    assert "fovea max_depth=0 shadows='none'" in text and "speed:" in text and "0-5" in text


def test_the_log_gives_each_evaluation_s_whole_frame_flip_beside_plain_s(spheres):
    """Each evaluation's log line says its whole-frame FLIP (mean over the frames) and how far
    it is from plain foveation's, the figure the cost-accuracy chart plots."""
    scene, rig = spheres
    lines = []
    plan = plan_fidelity(
        scene,
        rig,
        FOVEATION,
        ("flip", 1.0),
        search=PlanSearch(gazes=GAZES, keys=KEYS, options=CHAIN),
        config=CONFIG,
        log=lines.append,
    )
    plain = plan.plain_metric[0]
    assert lines[0].startswith("plain: ") and lines[0].endswith(f"FLIP {plain:.4f}")
    assert len(lines) == 1 + len(plan.steps)
    for line, step in zip(lines[1:], plan.steps, strict=True):
        assert line.endswith(f"FLIP {step.metric:.4f} ({step.metric - plain:+.4f})"), line


def test_a_plan_that_is_not_faster_says_whether_it_traces_fewer_rays(loose):
    """Timing decides (the machine's); the rays are counted: the note of no gain says which it
    traced, fewer or not (a plan at another density can trace more rays than plain foveation)."""
    plain = {"ms_per_frame": 10.0, "rays_per_frame": 1000.0}
    fewer = dataclasses.replace(
        loose, plain_cost=plain, plan_cost={"ms_per_frame": 11.0, "rays_per_frame": 800.0}
    )
    more = dataclasses.replace(
        loose, plain_cost=plain, plan_cost={"ms_per_frame": 11.0, "rays_per_frame": 1200.0}
    )
    faster = dataclasses.replace(
        loose, plain_cost=plain, plan_cost={"ms_per_frame": 9.0, "rays_per_frame": 800.0}
    )
    assert "no measured gain: the plan traces fewer rays and is not faster" in str(fewer)
    assert "no measured gain: the plan traces no fewer rays and is not faster" in str(more)
    assert "no measured gain" not in str(faster)


def test_zero_criterion_keeps_full_fidelity(spheres, loose):
    scene, rig = spheres
    strict = _plan(spheres, 0.0, ([FULL], [FULL], CHAIN))
    # The cheapest outside fidelity changes pixels there (mirrors and shadows), so it fails.
    assert [(s.region, s.passed) for s in strict.steps] == [("outside", False)]
    assert strict.steps[0].worst_added > 0
    assert strict.fidelity == (FULL, FULL, FULL)
    assert strict.foveation is strict.plain  # plain foveation itself: the same program
    assert strict.plan_cost["rays_per_frame"] == strict.plain_cost["rays_per_frame"]
    for key in KEYS:
        kwargs = {"gaze": (GAZES[0], GAZES[0]), "key": jax.random.key(key)}
        planned = render_foveated(scene, rig, foveation=strict.foveation, config=CONFIG, **kwargs)
        plain = render_foveated(scene, rig, foveation=FOVEATION, config=CONFIG, **kwargs)
        assert np.array_equal(planned.image, plain.image)
    np.testing.assert_array_equal(strict.added_ring_error[np.isfinite(strict.added_ring_error)], 0.0)


def test_middle_criterion_cheapens_only_what_stays_within(middle):
    # Outside without reflections and shadows adds little FLIP per ring on the spheres; the
    # periphery, where the mirror spheres are, adds far more than 0.05.
    assert middle.fidelity == (FULL, FULL, CHEAP)
    assert [(s.region, s.passed) for s in middle.steps] == [("outside", True), ("periphery", False)]
    assert middle.steps[1].worst_added > 0.05 >= middle.steps[0].worst_added
    assert middle.within


def test_the_plan_meets_the_criterion_per_ring_recomputed(spheres, middle):
    """Fresh renders of the plan, plain foveation and the full render, FLIP maps and rings
    computed here: the plan adds at most the threshold in every ring, and the plan's numbers
    are these."""
    scene, rig = spheres
    ppd = HmdDisplay.from_camera(rig.eye_cameras()[0]).ppd
    sums = {"plan": 0.0, "plain": 0.0}
    pixels = 0
    for key in KEYS:
        ref = render_stereo(scene, rig, spp=1, key=jax.random.key(key), config=CONFIG).image
        for name, fov in (("plan", middle.foveation), ("plain", FOVEATION)):
            frame = render_foveated(
                scene, rig, gaze=(GAZES[0], GAZES[0]), foveation=fov, key=jax.random.key(key), config=CONFIG
            )
            ecc = np.concatenate(list(frame.eccentricity), axis=1)
            _, emap = flip(frame.image, ref, ppd=ppd, return_map=True)
            rings = error_by_eccentricity(frame.image, ref, ecc, error_map=emap)
            sums[name] = sums[name] + np.nan_to_num(rings.mean_error) * rings.pixels
        pixels = pixels + rings.pixels
    seen = pixels > 0
    plan_rings = sums["plan"][seen] / pixels[seen]
    plain_rings = sums["plain"][seen] / pixels[seen]
    assert np.all(plan_rings - plain_rings <= 0.05)
    assert np.any(plan_rings - plain_rings > 0)  # the plan did change the frame
    np.testing.assert_allclose(middle.ring_error[: len(plan_rings)], plan_rings, atol=1e-6)
    np.testing.assert_allclose(middle.plain_ring_error[: len(plain_rings)], plain_rings, atol=1e-6)


def _two_density_plan(spheres) -> FidelityPlan:
    """The loose plan at densities (2, 4) and (4, 8)."""
    scene, rig = spheres
    search = PlanSearch(gazes=GAZES, keys=KEYS, options=CHAIN, densities=[(2, 4), (4, 8)])
    return plan_fidelity(scene, rig, FOVEATION, ("flip", 1.0), search=search, config=CONFIG)


def test_densities_are_planned_and_the_cheapest_is_kept(spheres):
    """With `densities`, the search runs at each sampling density that passes at full fidelity;
    the plan is one of them (the faster of their plans timed in turn: which one is the
    machine's, so not pinned), with its fidelity searched, and says its blocks when they
    changed."""
    plan = _two_density_plan(spheres)
    density = [s for s in plan.steps if s.region == "density"]
    assert [(s.candidate, s.passed) for s in density] == [((4, 8), True)]
    assert plan.fidelity == (CHEAP, CHEAP, CHEAP)
    assert tuple(plan.foveation.blocks) in {(2, 4), (4, 8)}
    assert plan.plain is FOVEATION
    if tuple(plan.foveation.blocks) == (4, 8):
        assert plan.describe_plan().startswith("blocks (4, 8); ")
    else:
        assert "blocks" not in plan.describe_plan()
    assert [c["blocks"] for c in plan.choices] == [(2, 4), (4, 8)]
    assert all(c["fidelity"] == (CHEAP, CHEAP, CHEAP) for c in plan.choices)
    fastest = min(plan.choices, key=lambda c: c["ms_per_frame"])
    assert tuple(plan.foveation.blocks) == fastest["blocks"]
    assert "each density's plan, timed in turn: blocks (2, 4) " in str(plan)


@pytest.mark.parametrize("faster", [(2, 4), (4, 8)])
def test_the_plan_is_the_density_faster_when_timed_in_turn(spheres, monkeypatch, faster):
    """Between the densities' plans, the one faster when they are rendered in turn over the
    frames is kept, whatever the search's single timings said: here a frame's time is set by
    its blocks (the other density 1 s slower), except in the search, where it says the
    opposite."""
    import fovjax.eval._plan as plan_module

    real = plan_module._Judge.render
    choosing = [False]

    def timed(self, foveation, gaze, key):
        frame = real(self, foveation, gaze, key)
        slow = (tuple(foveation.blocks) != faster) == choosing[0]
        stats = dataclasses.replace(frame.stats, render_seconds=1.0 + slow)
        return dataclasses.replace(frame, stats=stats)

    real_judge = plan_module._Judge.__call__

    def judged(self, foveation):
        choosing[0] = False
        try:
            return real_judge(self, foveation)
        finally:
            choosing[0] = True  # every render outside an evaluation: the choice and the final timing

    monkeypatch.setattr(plan_module._Judge, "render", timed)
    monkeypatch.setattr(plan_module._Judge, "__call__", judged)
    plan = _two_density_plan(spheres)
    assert tuple(plan.foveation.blocks) == faster
    times = {c["blocks"]: c["ms_per_frame"] for c in plan.choices}
    assert times[faster] == 1000.0 and max(times.values()) == 2000.0


def test_a_frame_tolerance_bounds_the_whole_frame_too(spheres, loose):
    """With `frame_tolerance`, a candidate within the ring threshold still fails where the whole
    frame's FLIP rises more than the tolerance above plain foveation's: at 0 (and a ring threshold
    that takes anything, as `loose`'s), the cheap candidates that raised it fail, the plan's
    FLIP is at most plain's, and the loose plan's was above it."""
    assert loose.plan_metric[0] > loose.plain_metric[0]  # the bound has something to refuse
    scene, rig = spheres
    search = PlanSearch(gazes=GAZES, keys=KEYS, options=CHAIN, frame_tolerance=0.0)
    plan = plan_fidelity(scene, rig, FOVEATION, ("flip", 1.0), search=search, config=CONFIG)
    plain = plan.plain_metric[0]
    refused = [s for s in plan.steps if not s.passed]
    assert refused and all(s.worst_added <= 1.0 and s.metric > plain for s in refused)
    assert all(s.metric <= plain + 1e-12 for s in plan.steps if s.passed)  # means computed apart
    assert plan.plan_metric[0] <= plain + 1e-12 and plan.frame_tolerance == 0.0
    assert "and per frame <= 0," in str(plan)


def test_a_density_that_fails_at_full_fidelity_is_no_candidate(spheres):
    scene, rig = spheres
    plan = plan_fidelity(
        scene,
        rig,
        FOVEATION,
        ("flip", 0.0),
        search=PlanSearch(gazes=GAZES, keys=KEYS, options=[FULL], densities=[(2, 4), (4, 8)]),
        config=CONFIG,
    )
    # Sparser blocks change pixels, so at threshold 0 they fail; plain foveation is the plan.
    assert [(s.region, s.candidate, s.passed) for s in plan.steps] == [("density", (4, 8), False)]
    assert plan.steps[0].worst_added > 0
    assert plan.foveation is FOVEATION


def test_default_options_are_a_monotone_chain():
    chain = default_options(5, lights=2)
    assert chain[0] == Fidelity()
    depths = [5 if f.max_depth is None else f.max_depth for f in chain]
    shadows = [("all", "brightest", "none").index(f.shadows) for f in chain]
    assert depths == sorted(depths, reverse=True) and shadows == sorted(shadows)
    # At SPP 1 the spp step is no step at all (skipped).
    assert chain[-1] == CHEAP and len(chain) == len(DEFAULT_STEPS)
    # One light: "brightest" is "all"; max_depth 1: the depth-2 step is skipped.
    assert [f.shadows for f in default_options(1, lights=1)] == ["all", "all", "none"]
    assert [f.max_depth for f in default_options(1, lights=1)] == [None, 0, 0]
    # At SPP 4 the chain gains the 1-SPP step after depth 1, and keeps it to the end.
    at4 = default_options(5, lights=1, spp=4)
    assert len(at4) == len(default_options(5, lights=1, spp=1)) + 1
    spps = [4 if f.spp is None else f.spp for f in at4]
    assert spps == sorted(spps, reverse=True) and at4[-1].spp == 1
    assert at4[3] == Fidelity(max_depth=1, spp=1)


def test_default_options_take_first_steps_first_and_keep_them():
    # A lever given in `first` comes before the default steps and stays in every later
    # candidate, with every field of the default candidates (the spp step included); a step
    # that changes nothing (spp 1 again) is no second candidate.
    chain = default_options(5, lights=1, spp=4, first=({"lod": "auto"}, {"spp": 1}))
    assert chain[:3] == (Fidelity(), Fidelity(lod="auto"), Fidelity(lod="auto", spp=1))
    assert all(f.lod == "auto" and f.spp == 1 for f in chain[2:])
    assert chain[3:] == (
        Fidelity(max_depth=2, lod="auto", spp=1),
        Fidelity(max_depth=1, lod="auto", spp=1),
        Fidelity(max_depth=0, lod="auto", spp=1),
        Fidelity(max_depth=0, shadows="none", lod="auto", spp=1),
    )
    assert len(set(chain)) == len(chain)
    # The skipping rules hold for them too: an spp step at the frame's SPP is no step.
    assert default_options(5, lights=1, spp=1, first=({"spp": 1},)) == default_options(5, lights=1, spp=1)
    with pytest.raises(ValueError, match=r"first.*'lod=auto'"):
        default_options(5, first=("lod=auto",))


def test_top_level_export():
    assert fovjax.plan_fidelity is plan_fidelity
    with pytest.raises(AttributeError, match="no_such_thing"):
        fovjax.no_such_thing  # noqa: B018


# -- bad input: a ValueError naming the argument and the value, before anything is rendered ---
class Rendered(BaseException):
    pass


def _trap(*args, **kwargs):
    raise Rendered("rendered before refusing the input")


BAD = [
    ({"scene": "atrium"}, "scene"),
    ({"rig": None}, "rig"),
    ({"foveation": (5, 10)}, "foveation"),
    ({"config": {"max_depth": 2}}, "config"),
    ({"criterion": ("psnr", 30)}, "'psnr'"),
    ({"criterion": ("flip", float("nan"))}, "threshold nan"),
    ({"criterion": ("flip", -0.1)}, "threshold -0.1"),
    ({"criterion": ("flip", 2)}, "threshold 2"),
    ({"criterion": ("flip",)}, "criterion"),
    ({"criterion": "flip"}, "criterion 'flip'"),
    ({"gazes": []}, "gazes"),
    ({"gazes": [(0.5, 1.2)]}, r"gazes\[0\].*off-screen"),
    ({"gazes": [(0.5, 0.5), (float("nan"), 0.5)]}, r"gazes\[1\].*NaN"),
    ({"gazes": [(0.1, 0.2, 0.3)]}, r"gazes\[0\]"),
    ({"keys": []}, "keys"),
    ({"keys": [0, -1]}, r"keys\[1\] -1"),
    ({"keys": [1.5]}, r"keys\[0\] 1.5"),
    ({"keys": [True]}, r"keys\[0\] True"),
    ({"repeats": 0}, "repeats 0"),
    ({"frame_tolerance": -0.001}, "frame_tolerance -0.001"),
    ({"frame_tolerance": float("nan")}, "frame_tolerance nan"),
    ({"frame_tolerance": float("inf")}, "frame_tolerance inf"),
    ({"frame_tolerance": "0.005"}, "frame_tolerance '0.005'"),
    ({"frame_tolerance": True}, "frame_tolerance True"),
    ({"render_kwargs": ["envmap"]}, "render_kwargs"),
    ({"options": []}, "options"),
    ({"options": [FULL, "cheap"]}, "options"),
    ({"options": [FULL, Fidelity(max_depth=3)]}, r"options \(fovea\)\[1\] max_depth 3.*max_depth 2"),
    ({"options": ([FULL], [], [FULL])}, r"options \(periphery\).*empty"),
    ({"options": ([FULL], [FULL], [FULL, 7])}, r"options \(outside\)\[1\] 7"),
    ({"options": FULL}, "options"),
    ({"densities": []}, "densities"),
    ({"densities": "2,4"}, "densities"),
    ({"densities": [(2, 4), (2, 3)]}, r"densities\[1\] \(2, 3\)"),
    ({"densities": [(2, 4), (2.0, 4)]}, r"densities\[1\].*pair of integers"),
    ({"densities": [(2, 4), (2, 4)]}, r"densities\[1\].*given twice"),
    (
        {"foveation": Foveation.thesis(0, fidelity=(FULL, FULL, Fidelity(max_depth=4)))},
        r"foveation.fidelity \(outside\) max_depth 4",
    ),
]


@pytest.mark.no_typecheck
@pytest.mark.parametrize(("change", "message"), BAD)
def test_bad_arguments_fail_before_rendering(spheres, monkeypatch, change, message):
    monkeypatch.setattr(fovjax.render, "render_stereo", _trap)
    monkeypatch.setattr(fovjax.foveate, "render_foveated", _trap)
    scene, rig = spheres
    args = {"scene": scene, "rig": rig, "foveation": FOVEATION, "criterion": ("flip", 0.05)}
    searched = {"gazes": GAZES, "keys": KEYS}
    kwargs = {"config": CONFIG}
    for name, value in change.items():
        where = args if name in args else searched if name in PlanSearch.__dataclass_fields__ else kwargs
        where[name] = value
    with pytest.raises(ValueError, match=message) as err:
        kwargs["search"] = PlanSearch(**searched)
        plan_fidelity(args["scene"], args["rig"], args["foveation"], args["criterion"], **kwargs)
    assert "plan_fidelity" in str(err.value)
