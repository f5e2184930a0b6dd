"""The thesis's user study emulated as video: an animated sequence through the scene at the
HMD's frame rate, with head motion and a gaze per frame, rendered full and foveated at every
study level, judged by FovVideoVDP in video mode on a display model of the NVIS SX111, and the
pair, ramp and slider tests answered from those JODs by the automatic observers.

    import fovjax, fovjax.eval as fe
    animation = fe.StudyAnimation(eye_width=160, eye_height=128, frames=30)  # and levels, gaze, rule, ...
    study = fe.video_study(fovjax.scenes.atrium(), animation)
    study.jods                  # {(5.0, 10.0): MetricValue(JOD), ...} worse eye, per level
    study.majorities            # {"pair": 12.5 or None, "ramp up": ..., "ramp down": ..., "slider": ...}
    study.write("out/video_study")

What the thesis gives (chapter 5.2, section 2.1.3, section 4.3) and what is assumed here:

- Scene: Sponza at SPP 4, both eyes (2 x 1280 x 1024); here a fovjax scene (the atrium is the
  Sponza stand-in) at a reduced resolution (`eye_width` x `eye_height`).
- Animation: "short animated sequences"; the thesis describes no camera path. Here the head walks
  straight along the default view direction at `walk_speed` m/s (level, 1 m/s by default: a slow
  walk) while the head turns: `fovjax.devices.SyntheticHeadSource`'s look-around (yaw ±20°,
  pitch ±5°, period 8 s), sampled at the frame times. Head tracking (InertiaCube3) was live in the
  thesis's application, so head motion is part of what participants saw.
- Frame rate: `fps`, default 60 Hz, the frame rate of NVIS's LCOS HMDs ("per color, per frame,
  at 60 Hz", NVIS's Advanced Video Control Unit user guide; the thesis states none). The thesis's
  renderer reached 26 fps full and 48 fps foveated at SPP 4 on its Sponza, so its participants
  saw new frames less often than the display refreshed.
- Gaze: "scanpath" (default) — `fovjax.devices.Scanpath` (fixations of 218 ms mean and
  main-sequence saccades), the same point in both eyes, amplitudes in degrees of the SX111
  display; the foveation and the metric take the same gaze every frame (a perfect tracker).
  "fixed" — the display centre every frame: what the thesis's participants did (its eye tracker's
  mirror was damaged, so participants were asked to look at a marked point at the centre of the
  foveal region).
- Foveation regions: the thesis's own region reading (`Foveation.thesis_measured`: planar
  eccentricity at the SX111's 64° over the display's rows, i.e. 16 pixels per degree at 1024 rows,
  2 at 128) with the sampling `rule` ("either", fovjax's reading of the text, by default;
  "thesis-measured", the sampling the thesis's Table 2 implies). Sampling key: `keys="fresh"`
  (default) a new key per frame, the same for the full and the foveated render (stochastic
  anti-aliasing in both; the foveated frame's random sample pattern changes every frame);
  `keys="fixed"` the same key every frame (a pattern fixed on the display). The thesis does not
  say which its renderer did.
- Display model (`sx111_display`): per eye `eye_width` x `eye_height` pixels over the SX111's
  64° vertical (thesis 2.1.3: 102° x 64° in all, 1280 x 1024 per eye; horizontal per eye
  2·atan(tan 32° · 1280/1024) = 75.9°), so at a reduced resolution the field of view stays and
  the pixels per degree scale with it. Peak luminance: the thesis gives none; 100 cd/m² by
  default (pyfvvdp's generic `standard_hmd`), contrast 1000:1, no ambient light (closed HMD).
- Verdict: 10 − JOD per level is the difference d the observers judge (`observers_from_comparison`,
  seen when d > `JND_JOD` = 1), then `run_study` and `study_majorities`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ._metrics import JND_JOD, HmdDisplay, MetricValue, fovvdp
from ._pareto import write_csv
from ._protocols import APPENDIX_LEVELS, Response, _check_levels, run_study
from ._study import THESIS_LEVEL, ObserverPanel, observers_from_comparison, study_majorities

SX111_EYE = (1280, 1024)  # pixels per eye (thesis 2.1.3)
SX111_VFOV_DEG = 64.0  # vertical field of view (thesis 2.1.3: 102° x 64°)
SX111_FPS = 60.0  # NVIS's LCOS HMDs run at 60 Hz (NVIS AVCU user guide); the thesis gives none
STUDY_SPP = 4  # thesis 5.2
DEFAULT_PEAK_LUMINANCE = 100.0  # cd/m²; the thesis gives none (pyfvvdp's standard_hmd)
GAZE_MODES = ("scanpath", "fixed")
KEY_MODES = ("fresh", "fixed")  # a new sampling key per frame, or the same key every frame
WALK_SPEED = 1.0  # m/s along the default view direction
MIN_FRAMES = 2


def sx111_display(
    eye_width: int = SX111_EYE[0],
    eye_height: int = SX111_EYE[1],
    *,
    peak_luminance: float = DEFAULT_PEAK_LUMINANCE,
    contrast: float = 1000.0,
    vfov_deg: float = SX111_VFOV_DEG,
) -> HmdDisplay:
    """One eye of the NVIS SX111 as FovVideoVDP sees it: `eye_width` x `eye_height` pixels over
    `vfov_deg` vertically (64°, thesis 2.1.3; square pixels, so 75.9° horizontally at 1280 x 1024).
    At a reduced resolution the field of view stays and the pixels per degree scale down."""
    if int(eye_width) < 1 or int(eye_height) < 1:
        raise ValueError(f"sx111_display: resolution must be positive, got {eye_width}x{eye_height}")
    if not 0 < vfov_deg < 180:
        raise ValueError(f"sx111_display: vfov_deg must be in (0, 180), got {vfov_deg}")
    tan_half_v = math.tan(math.radians(vfov_deg) / 2.0)
    hfov = 2.0 * math.degrees(math.atan(tan_half_v * eye_width / eye_height))
    return HmdDisplay(int(eye_width), int(eye_height), hfov, peak_luminance=peak_luminance, contrast=contrast)


@dataclasses.dataclass(frozen=True)
class StudySequence:
    """The rendered animation: `reference` (F, H, 2W, 3) full renders and `foveated[level]` the
    same frames foveated at each (fovea, periphery) level, linear RGB side by side; the per-frame
    `gaze` (F, 2, 2) (normalised, per eye), `head_poses` (F, 3) yaw/pitch/roll degrees and
    `positions` (F, 3) head centres; `primary_rays` per level (mean per frame; key None: the
    full render); `render_seconds` and `compile_seconds` in all; `traces`: how many programs were
    traced per entry point while rendering it ({"stereo": 1, "foveated": 1} when the sequence
    compiled once for the full and once for every foveated frame)."""

    reference: np.ndarray
    foveated: dict
    gaze: np.ndarray
    head_poses: np.ndarray
    positions: np.ndarray
    fps: float
    spp: int
    rule: str
    gaze_mode: str
    key_mode: str
    scene: str
    primary_rays: dict
    render_seconds: float
    compile_seconds: float
    traces: dict
    regions: str = "thesis"
    # The foveation method of the foveated frames (`fovjax.foveate.METHODS`), and per level the
    # mean pixels per frame a temporal method showed from its history (0 for the thesis's).
    method: str = "thesis"
    reused_pixels: dict = dataclasses.field(default_factory=dict)

    @property
    def frames(self) -> int:
        return int(self.reference.shape[0])

    @property
    def eye_width(self) -> int:
        return int(self.reference.shape[2] // 2)

    @property
    def eye_height(self) -> int:
        return int(self.reference.shape[1])

    @property
    def levels(self) -> tuple[tuple[float, float], ...]:
        return tuple(self.foveated)

    @property
    def duration_s(self) -> float:
        return self.frames / self.fps


def _check_int(value, name: str, lo: int, where: str = "StudyAnimation") -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < lo:
        raise ValueError(f"{where}: {name} must be a whole number >= {lo}, got {value!r}")
    return int(value)


def _check_positive(value, name: str) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not (math.isfinite(value) and value > 0)
    ):
        raise ValueError(f"StudyAnimation: {name} must be a finite number > 0, got {value!r}")
    return float(value)


def _check_args(eye_width, eye_height, frames, fps, spp, gaze, rule, walk_speed, seed, levels, keys="fresh"):
    """Every field of a `StudyAnimation`, checked and normalised."""
    from ..foveate import SAMPLING_RULES

    eye_width = _check_int(eye_width, "eye_width", 8)
    eye_height = _check_int(eye_height, "eye_height", 8)
    frames = _check_int(frames, "frames", MIN_FRAMES)
    fps = _check_positive(fps, "fps")
    spp = _check_int(spp, "spp", 1)
    if math.isqrt(spp) ** 2 != spp:
        raise ValueError(f"StudyAnimation: spp must be a perfect square (1, 4, 9, 16, ...), got {spp}")
    if gaze not in GAZE_MODES:
        raise ValueError(f"StudyAnimation: gaze must be one of {GAZE_MODES}, got {gaze!r}")
    if keys not in KEY_MODES:
        raise ValueError(f"StudyAnimation: keys must be one of {KEY_MODES}, got {keys!r}")
    if rule not in SAMPLING_RULES:
        raise ValueError(f"StudyAnimation: rule must be one of {SAMPLING_RULES}, got {rule!r}")
    if (
        isinstance(walk_speed, bool)
        or not isinstance(walk_speed, int | float)
        or not (math.isfinite(walk_speed) and walk_speed >= 0)
    ):
        raise ValueError(f"StudyAnimation: walk_speed must be a finite number >= 0 (m/s), got {walk_speed!r}")
    seed = _check_int(seed, "seed", 0)
    if seed > 2**32 - 1 - frames:
        raise ValueError(
            f"StudyAnimation: seed must be <= {2**32 - 1 - frames} (one key per frame), got {seed}"
        )
    levels = _check_levels(levels, "StudyAnimation")
    return eye_width, eye_height, frames, fps, spp, float(walk_speed), seed, levels


def _animation(animation, where: str) -> StudyAnimation:
    if animation is None:
        return StudyAnimation()
    if not isinstance(animation, StudyAnimation):
        raise TypeError(f"{where}: animation must be a StudyAnimation, got {type(animation).__name__}")
    return animation


def _head_poses(frames: int, fps: float) -> np.ndarray:
    from ..devices import SyntheticHeadSource

    source = SyntheticHeadSource(rate=fps, duration=(frames - 1) / fps, speed=None)
    angles = []
    with source:
        for f in range(frames):
            pose = source.read()
            if pose is None:  # the source's duration covers every frame: never expected
                raise RuntimeError(f"the synthetic head source ended at frame {f} of {frames}")
            angles.append((pose.yaw, pose.pitch, pose.roll))
    return np.asarray(angles, np.float32)


def _gazes(mode: str, frames: int, fps: float, seed: int, display: HmdDisplay) -> np.ndarray:
    from ..devices import Scanpath

    if mode == "fixed":
        return np.full((frames, 2, 2), 0.5, np.float32)
    path = Scanpath(seed, display_fov_deg=(display.hfov_deg, display.vfov_deg))
    points = np.asarray([path.position(f / fps) for f in range(frames)], np.float32)
    return np.repeat(points[:, None, :], 2, axis=1)


@dataclasses.dataclass(frozen=True)
class StudyAnimation:
    """What the study's animation is (see the module docstring): `frames` frames at `fps`, per
    eye `eye_width` x `eye_height`, `spp` samples per pixel, foveated at each (fovea,
    periphery) of `levels` with the sampling `rule` and the `regions` reading
    (`fovjax.foveate.with_regions`: "thesis", the thesis's own, so the levels compare with its
    participants' answers; or "angle", fovjax's exact-angle regions, about half the area on the
    90° rig); the gaze ("scanpath" or "fixed"), the walk's `walk_speed` (m/s), and `seed`: the
    scanpath's seed and the first frame's key (frame f uses seed + f with `keys="fresh"`, seed
    with "fixed"). `method`: the foveation method of the foveated frames (a name of
    `fovjax.foveate.METHODS`; default the thesis's); a temporal method (`Weier2016`,
    `Patney2016`) carries its history from frame to frame at each level, from none at the
    first frame.

    Raises:
        ValueError: any bad field, naming it, its value and what was expected.
    """

    levels: Sequence = APPENDIX_LEVELS
    eye_width: int = 160
    eye_height: int = 128
    frames: int = 30
    fps: float = SX111_FPS
    spp: int = STUDY_SPP
    gaze: str = "scanpath"
    rule: str = "either"
    regions: str = "thesis"
    walk_speed: float = WALK_SPEED
    seed: int = 0
    keys: str = "fresh"
    method: str = "thesis"

    def __post_init__(self):
        from ..foveate import METHODS, REGION_READINGS

        if not isinstance(self.method, str) or self.method not in METHODS:
            raise ValueError(f"StudyAnimation: method must be one of {tuple(METHODS)}, got {self.method!r}")

        checked = _check_args(
            self.eye_width,
            self.eye_height,
            self.frames,
            self.fps,
            self.spp,
            self.gaze,
            self.rule,
            self.walk_speed,
            self.seed,
            self.levels,
            self.keys,
        )
        if self.regions not in REGION_READINGS:
            raise ValueError(
                f"StudyAnimation: regions must be one of {REGION_READINGS}, got {self.regions!r}"
            )
        *numbers, levels = checked
        names = ("eye_width", "eye_height", "frames", "fps", "spp", "walk_speed", "seed")
        for name, value in zip(names, numbers, strict=True):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "levels", tuple(levels))


def study_sequence(
    scene,
    animation: StudyAnimation | None = None,
    *,
    config=None,
    progress: Callable[[str], None] | None = None,
) -> StudySequence:
    """Render the study's animation (`StudyAnimation`, default `StudyAnimation()`; see the module
    docstring) full and foveated at every level, with the `RenderConfig` `config`. Head pose,
    head position, gaze, sampling key and the foveation thresholds change per frame as traced
    values: the full render compiles once and the foveated render once for the whole
    sequence. `progress(text)` is called once per frame rendered."""
    import equinox as eqx
    import jax

    from ..foveate import FoveatedRenderer, Foveation, with_regions
    from ..render import TRACE_COUNTS, RenderConfig, StereoRig
    from ..scenes import default_camera

    animation = _animation(animation, "study_sequence")
    a = animation
    eye_width, eye_height, frames, fps, spp = a.eye_width, a.eye_height, a.frames, a.fps, a.spp
    levels, seed, gaze, rule, regions, keys = a.levels, a.seed, a.gaze, a.rule, a.regions, a.keys
    walk_speed = a.walk_speed
    config = config or RenderConfig()
    tick = progress or (lambda text: None)
    display = sx111_display(eye_width, eye_height)
    pose = default_camera(scene)
    rig0 = StereoRig.from_pose(pose, eye_width=eye_width, eye_height=eye_height)
    start = np.asarray(pose.position, np.float32)
    forward = np.asarray(pose.look_at, np.float64) - start
    forward[1] = 0.0  # walk level
    norm = float(np.linalg.norm(forward))
    forward = (forward / norm if norm > 0 else np.zeros(3)).astype(np.float32)
    times = np.arange(frames, dtype=np.float32) / np.float32(fps)
    positions = start[None, :] + (walk_speed * times)[:, None] * forward[None, :]
    poses = _head_poses(frames, fps)
    gazes = _gazes(gaze, frames, fps, seed, display)
    # The scene prepared once; a renderer per level shares it (only the image is read).
    base = FoveatedRenderer(scene, rig0, Foveation(spp=spp), config, diagnostics=())
    # One renderer per level, each with its own history where the method keeps one (`with_rig`
    # moves a renderer and keeps its history).
    renderers = {
        level: base.with_foveation(
            with_regions(Foveation.thesis(level, rule=rule, spp=spp, method=a.method), regions, eye_height)
        )
        for level in levels
    }
    reused = {level: [] for level in levels}
    traced_before = dict(TRACE_COUNTS)
    reference = []
    foveated = {level: [] for level in levels}
    rays = {None: [], **{level: [] for level in levels}}
    render_s = compile_s = 0.0
    for f in range(frames):
        rig = eqx.tree_at(lambda r: r.position, rig0, positions[f])
        key = jax.random.key(seed + f if keys == "fresh" else seed)
        frame = base.with_rig(rig).render_full(head_pose=poses[f], key=key)
        reference.append(frame.image)
        rays[None].append(frame.stats.primary_rays)
        render_s += frame.stats.render_seconds
        compile_s += frame.stats.compile_seconds
        for level, renderer in renderers.items():
            fov = renderer.with_rig(rig).render(gazes[f], head_pose=poses[f], key=key)
            foveated[level].append(fov.image)
            rays[level].append(fov.stats.primary_rays)
            reused[level].append(fov.foveation.reused)
            render_s += fov.stats.render_seconds
            compile_s += fov.stats.compile_seconds
        tick(f"frame {f + 1}/{frames}")
    traces = {k: TRACE_COUNTS[k] - traced_before.get(k, 0) for k in ("stereo", "foveated")}
    return StudySequence(
        reference=np.stack(reference),
        foveated={level: np.stack(images) for level, images in foveated.items()},
        gaze=gazes,
        head_poses=poses,
        positions=positions,
        fps=fps,
        spp=spp,
        rule=rule,
        regions=regions,
        gaze_mode=gaze,
        key_mode=keys,
        scene=str(getattr(scene, "name", "scene")),
        primary_rays={k: float(np.mean(v)) for k, v in rays.items()},
        method=a.method,
        reused_pixels={k: float(np.mean(v)) for k, v in reused.items()},
        render_seconds=render_s,
        compile_seconds=compile_s,
        traces=traces,
    )


def judge_sequence(
    sequence: StudySequence, display: HmdDisplay | None = None, *, foveated: bool = True
) -> dict:
    """FovVideoVDP (video mode at the sequence's frame rate, fixation = the sequence's gaze per
    frame, worse eye) of every level's foveated frames against the full render: {level:
    MetricValue}. `display` defaults to `sx111_display` at the sequence's resolution."""
    display = display or sx111_display(sequence.eye_width, sequence.eye_height)
    if (display.width_px, display.height_px) != (sequence.eye_width, sequence.eye_height):
        raise ValueError(
            f"judge_sequence: display {display.width_px}x{display.height_px} differs from the sequence's "
            f"{sequence.eye_width}x{sequence.eye_height} per eye (use display.with_resolution)"
        )
    return {
        level: fovvdp(
            images, sequence.reference, display, gaze_xy=sequence.gaze, foveated=foveated, fps=sequence.fps
        )
        for level, images in sequence.foveated.items()
    }


@dataclasses.dataclass(frozen=True)
class VideoStudy:
    """The study emulated on video: `sequence` (what was rendered), `display` (the metric's
    display model), `jods` {level: FovVideoVDP MetricValue}, `reference_jod` (the full render
    judged against itself: 10 when the metric is sound), `responses` of the automatic observers,
    `majorities` per test (`study_majorities`: the lowest fovea the majority accepts, None if
    none), `threshold` on 10 − JOD, `metric_seconds` (FovVideoVDP's time in all)."""

    sequence: StudySequence
    display: HmdDisplay
    jods: dict
    reference_jod: MetricValue | None
    responses: list[Response]
    majorities: dict
    threshold: float
    observers: int
    noise_sd: float
    metric_seconds: float

    def difference(self, level) -> float:
        return 10.0 - float(self.jods[level])

    def records(self) -> list[dict]:
        """One row per level (CSV-writable): the JOD (worse eye and each eye), d = 10 − JOD,
        whether a noise-free observer sees it, primary rays per frame, and the set-up."""
        s, d = self.sequence, self.display
        rows = []
        for level, jod in self.jods.items():
            rows.append(
                {
                    "scene": s.scene,
                    "fovea_deg": level[0],
                    "periphery_deg": level[1],
                    "spp": s.spp,
                    "method": s.method,
                    "rule": s.rule,
                    "regions": s.regions,
                    "gaze": s.gaze_mode,
                    "keys": s.key_mode,
                    "jod": float(jod),
                    "jod_left": jod.details.get("jod_left"),
                    "jod_right": jod.details.get("jod_right"),
                    "d": self.difference(level),
                    "seen": self.difference(level) > self.threshold,
                    "primary_rays_per_frame": s.primary_rays[level],
                    "full_primary_rays_per_frame": s.primary_rays[None],
                    "reused_pixels_per_frame": s.reused_pixels.get(level, 0.0),
                    "frames": s.frames,
                    "fps": s.fps,
                    "eye_width": s.eye_width,
                    "eye_height": s.eye_height,
                    "display_hfov_deg": d.hfov_deg,
                    "display_vfov_deg": d.vfov_deg,
                    "ppd_centre": d.ppd,
                    "peak_luminance": d.peak_luminance,
                    "reference_jod": None if self.reference_jod is None else float(self.reference_jod),
                }
            )
        return rows

    def verdict(self) -> list[dict]:
        """Per test, the level the observers' majority accepts beside the thesis's 12.5°/25°."""
        levels = dict(self.sequence.levels)
        return [
            {
                "test": test,
                "majority_fovea_deg": fovea,
                "majority_periphery_deg": None if fovea is None else levels.get(fovea),
                "thesis_fovea_deg": THESIS_LEVEL[0],
                "thesis_periphery_deg": THESIS_LEVEL[1],
            }
            for test, fovea in self.majorities.items()
        ]

    def write(self, out_dir) -> dict[str, Path]:
        """video_study.csv (per level), majority.csv (per test, beside the thesis's),
        responses.csv and the figures 66-68 with their tables (`write_study_report`)."""
        from ._charts import write_study_report
        from ._protocols import write_responses

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        paths = {
            "video_study": write_csv(self.records(), out / "video_study.csv"),
            "majority": write_csv(self.verdict(), out / "majority.csv"),
            "responses": write_responses(self.responses, out / "responses.csv"),
        }
        paths.update(write_study_report(self.responses, out, levels=self.sequence.levels))
        return paths


def verdict_from_jods(
    jods: dict,
    *,
    spp: int = STUDY_SPP,
    levels: Sequence = APPENDIX_LEVELS,
    observers: ObserverPanel | None = None,
) -> tuple[list[Response], dict]:
    """The pair, ramp and slider tests answered by the automatic `observers` (`ObserverPanel`,
    default `ObserverPanel()`) judging d = 10 − JOD at each level (seen when d > its threshold,
    `JND_JOD` by default): (responses, majorities)."""
    table = [
        {"fovea_deg": level[0], "periphery_deg": level[1], "spp": spp, "jod": float(jod)}
        for level, jod in jods.items()
    ]
    observer_list = observers_from_comparison(
        table, metric="jod", spp=spp, observers=observers, levels=levels, where="video study"
    )
    responses = run_study(observer_list, levels)
    return responses, study_majorities(responses, levels)


def video_study(
    scene,
    animation: StudyAnimation | None = None,
    *,
    observers: ObserverPanel | None = None,
    peak_luminance: float = DEFAULT_PEAK_LUMINANCE,
    check_reference: bool = True,
    config=None,
    sequence: StudySequence | None = None,
    progress: Callable[[str], None] | None = None,
) -> VideoStudy:
    """The thesis's user study on video (see the module docstring): render the animation
    (`study_sequence(scene, animation)`, or reuse `sequence`), judge every level with
    FovVideoVDP on the SX111 display model at the rendered resolution (`sx111_display`,
    `peak_luminance` cd/m²), and run the pair, ramp and slider tests with the automatic
    `observers` (`ObserverPanel`, default `ObserverPanel()`; `verdict_from_jods`). Every
    argument is checked before anything is rendered; FovVideoVDP needs the `[fvvdp]` extra
    (checked first too). `check_reference` also judges the full render against itself."""
    from ._metrics import _require

    if not (isinstance(peak_luminance, int | float) and math.isfinite(peak_luminance) and peak_luminance > 0):
        raise ValueError(f"video_study: peak_luminance must be a number > 0 (cd/m²), got {peak_luminance!r}")
    panel = ObserverPanel() if observers is None else observers
    if not isinstance(panel, ObserverPanel):
        raise TypeError(f"video_study: observers must be an ObserverPanel, got {type(panel).__name__}")
    if sequence is None:
        animation = _animation(animation, "video_study")
        _require("pyfvvdp", "fvvdp", "the video study's FovVideoVDP")
        sequence = study_sequence(scene, animation, config=config, progress=progress)
    elif animation is not None:
        raise ValueError("video_study: give animation= or sequence= (rendered from one), not both")
    display = sx111_display(sequence.eye_width, sequence.eye_height, peak_luminance=float(peak_luminance))
    start = time.perf_counter()
    jods = judge_sequence(sequence, display)
    reference_jod = None
    if check_reference:
        reference_jod = fovvdp(
            sequence.reference, sequence.reference, display, gaze_xy=sequence.gaze, fps=sequence.fps
        )
    metric_s = time.perf_counter() - start
    responses, majorities = verdict_from_jods(jods, spp=sequence.spp, levels=sequence.levels, observers=panel)
    return VideoStudy(
        sequence=sequence,
        display=display,
        jods=jods,
        reference_jod=reference_jod,
        responses=responses,
        majorities=majorities,
        threshold=JND_JOD if panel.threshold is None else float(panel.threshold),
        observers=int(panel.n),
        noise_sd=float(panel.noise_sd),
        metric_seconds=metric_s,
    )
