"""`failure_cases`: run the named cases on one scene and rig, sharing the full renders and one
compiled foveated program."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

from .._stability import FullRenders
from ._acuity_models import acuity_models, default_models, equal_budget_foveations
from ._after_saccade import after_saccade
from ._checkerboard import checkerboard
from ._common import (
    CASES,
    FailureReport,
)
from ._corner_gaze import corner_gaze
from ._high_spp import high_spp
from ._scanpath_flicker import scanpath_flicker
from ._tracking_error import tracking_error


def failure_cases(
    scene,
    rig,
    foveation=None,
    *,
    cases: Sequence[str] = CASES,
    config=None,
    small_resolution: tuple[int, int] = (128, 96),
    high_spp_values: Sequence[int] = (1, 16),
    models: Mapping[str, object] | None = None,
    progress: bool = True,
    options: Mapping[str, Mapping] | None = None,
) -> FailureReport:
    """Run the named `cases` (default all of `CASES`, described in `fovjax.eval._failures`'s
    docstring) on `scene` and `rig`.
    The acuity models' equal-budget foveations are made first and the reference model's (the
    thesis's by default, with the common ray budget) is the foveation of every other case, so
    they share one compiled program; `foveation` sets the thresholds (default the thesis's
    10°/20°). `high_spp` runs at `small_resolution` per eye. `options`: per-case keyword
    arguments (e.g. {"after_saccade": {"saccade": SaccadeTrial(latencies_s=(0.05,))}})."""
    from ...foveate import Foveation

    unknown = [c for c in cases if c not in CASES]
    if unknown or not cases:
        raise ValueError(f"failure_cases: unknown cases {unknown}; choose from {CASES}")
    options = dict(options or {})
    bad = [c for c in options if c not in CASES]
    if bad:
        raise ValueError(f"failure_cases: options for unknown cases {bad}; choose from {CASES}")
    foveation = foveation or Foveation.thesis(2)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(unit="frame", desc="failures")
    tick = (lambda: bar.update(1)) if bar is not None else None
    full = FullRenders(scene, rig, config)
    model_opts = dict(options.get("acuity_models", {}))
    gazes = model_opts.pop("gazes", ((0.5, 0.5), (0.3, 0.4)))
    models = models or default_models()
    budget = equal_budget_foveations(rig, foveation, models, gazes=gazes)
    base = budget.foveations[budget.reference]
    common = {"progress": tick}  # the render config: `full`'s, or given to the cases without it
    report = {}
    for name in cases:
        if bar is not None:
            bar.set_description(name)
        opts = dict(options.get(name, {}))
        if name == "corner_gaze":
            case = corner_gaze(full, base, **common, **opts)
        elif name == "tracking_error":
            fovs = opts.pop("foveations", [Foveation(2.0, 4.0, acuity=base.acuity), base])
            case = tracking_error(full, fovs, **common, **opts)
        elif name == "after_saccade":
            case = after_saccade(full, base, **common, **opts)
        elif name == "high_spp":
            small = dataclasses.replace(
                rig, eye_width=int(small_resolution[0]), eye_height=int(small_resolution[1])
            )
            opts.setdefault("spp", high_spp_values)
            thresholds = (float(foveation.fovea_deg), float(foveation.periphery_deg))
            case = high_spp(scene, small, thresholds, config=config, **common, **opts)
        elif name == "checkerboard":
            case = checkerboard(rig, base, config=config, **common, **opts)
        elif name == "acuity_models":
            case = acuity_models(
                full,
                foveation,
                gazes=gazes,
                budgets={foveation.rule: budget},
                models=models,
                **common,
                **model_opts,
            )
        else:
            case = scanpath_flicker(full, base, **common, **opts)
        report[name] = case
    if bar is not None:
        bar.close()
    return FailureReport(report)
