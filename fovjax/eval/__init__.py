"""Evaluation: image metrics against the full render, Pareto selection of configurations, CSV
tables and charts, and the thesis's user-study protocols with an automatic observer.

    import fovjax.eval as fe
    fe.psnr(test, ref)                        # MetricValue(name="PSNR", value=..., units="dB")
    fe.ssim(test, ref); fe.flip(test, ref, ppd=display.ppd)           # flip: extra [flip]
    display = fe.HmdDisplay.from_camera(camera)                       # per-eye display model
    fe.fovvdp(test, ref, display, gaze_xy=(0.4, 0.5))                 # extra [fvvdp], JOD
    fe.error_by_eccentricity(test, ref, eccentricity_deg)            # 5° rings
    fe.pareto_front(table, {"rays_per_frame": "min", "flip": "min"})
    fe.cheapest_within(table, cost="rays_per_frame", metric="jod_drop", threshold=fe.JND_JOD)
    # the cheapest per-region Fidelity adding at most 0.01 FLIP per 5° ring (extra [flip])
    plan = fe.plan_fidelity(scene, rig, Foveation.thesis(0), ("flip", 0.01)); print(plan)
    # jod_at(level): your FovVideoVDP JOD of that foveation level against the full render
    observer = fe.MetricObserver(lambda trial: 10 - jod_at(trial.level), threshold=fe.JND_JOD)
    fe.write_study_report(fe.run_study([observer]), "out/study")      # figures 66-68
    # or from a `fovjax compare` table: 15 observers judging 10 - JOD (else FLIP) per level
    observers = fe.observers_from_comparison(fe.read_csv("out/compare/comparison.csv"), spp=4)
    fe.study_majorities(fe.run_study(observers))                       # {"pair": 12.5, ...}
    # the study emulated on video: an animation, FovVideoVDP in video mode, the SX111 display
    study = fe.video_study(fovjax.scenes.atrium(), eye_width=160, eye_height=128, frames=30)
    study.jods, study.majorities                                       # per level; per test
"""

from ._charts import (
    plot_acuity_models,
    plot_after_saccade,
    plot_checkerboard,
    plot_corner_gaze,
    plot_cost_accuracy,
    plot_flicker,
    plot_high_spp,
    plot_metric_bars,
    plot_pair_test,
    plot_ramp_test,
    plot_ring_errors,
    plot_scanpath_flicker,
    plot_slider_test,
    plot_tracking_error,
    write_study_report,
)
from ._compare import DEFAULT_CRITERION, DEFAULT_GAZES, HIGHER_IS_BETTER, Comparison, compare_thresholds
from ._failures import (
    CASES as FAILURE_CASES,
)
from ._failures import (
    FITTED_MAR,
    AcuityTerms,
    EqualBudget,
    FailureCase,
    FailureReport,
    acuity_models,
    after_saccade,
    checkerboard,
    checkerboard_scene,
    corner_gaze,
    default_models,
    equal_budget_foveations,
    failure_cases,
    high_spp,
    offset_gaze,
    scanpath_flicker,
    tracking_error,
)
from ._inspect import SceneInspection, inspect_scene
from ._metrics import (
    JND_JOD,
    HmdDisplay,
    MetricValue,
    MissingExtraError,
    RingErrors,
    _require,
    display_encode,
    error_by_eccentricity,
    flip,
    fovvdp,
    gaussian_window,
    luminance,
    pixels_per_degree,
    psnr,
    ssim,
    ssim_map,
)
from ._pareto import (
    Choice,
    as_records,
    cheapest_within,
    mean_interval,
    pareto_front,
    read_csv,
    write_csv,
)
from ._plan import (
    DEFAULT_PLAN_GAZES,
    DEFAULT_STEPS,
    FidelityPlan,
    PlanStep,
    default_options,
    plan_fidelity,
)
from ._protocols import (
    APPENDIX_LEVELS,
    DECISION_RULE,
    PAIR_ANSWERS,
    RAMP_ANSWERS,
    RESULT_FIELDS,
    MetricObserver,
    Response,
    ResultsFileError,
    Trial,
    analyse_pair,
    analyse_ramp,
    analyse_slider,
    majority_level,
    pair_trials,
    ramp_trials,
    read_responses,
    run_study,
    slider_trial,
    study_trials,
    wilson_interval,
    write_responses,
)
from ._shard import FrameBatch, frame_mesh, render_foveated_batch, render_stereo_batch
from ._stability import (
    FLICKER_REGIONS,
    KEY_MODES,
    FullRenders,
    StabilityResult,
    flicker,
    gaze_sequence,
    region_masks,
    temporal_stability,
)
from ._study import (
    MAJORITY_TESTS,
    STUDY_METRICS,
    THESIS_LEVEL,
    LevelDifference,
    default_metric,
    difference_from_comparison,
    observers_from_comparison,
    study_majorities,
)
from ._video_study import (
    GAZE_MODES as VIDEO_GAZE_MODES,
)
from ._video_study import (
    StudySequence,
    VideoStudy,
    judge_sequence,
    study_sequence,
    sx111_display,
    verdict_from_jods,
    video_study,
)

__all__ = [
    "DEFAULT_PLAN_GAZES",
    "DEFAULT_STEPS",
    "FidelityPlan",
    "PlanStep",
    "default_options",
    "plan_fidelity",
    "SceneInspection",
    "inspect_scene",
    "DEFAULT_CRITERION",
    "DEFAULT_GAZES",
    "HIGHER_IS_BETTER",
    "Comparison",
    "compare_thresholds",
    "FrameBatch",
    "frame_mesh",
    "render_foveated_batch",
    "render_stereo_batch",
    "APPENDIX_LEVELS",
    "DECISION_RULE",
    "JND_JOD",
    "PAIR_ANSWERS",
    "RAMP_ANSWERS",
    "RESULT_FIELDS",
    "Choice",
    "HmdDisplay",
    "MetricObserver",
    "MetricValue",
    "MissingExtraError",
    "require_extra",
    "Response",
    "ResultsFileError",
    "RingErrors",
    "Trial",
    "analyse_pair",
    "analyse_ramp",
    "analyse_slider",
    "as_records",
    "cheapest_within",
    "display_encode",
    "error_by_eccentricity",
    "flip",
    "fovvdp",
    "gaussian_window",
    "luminance",
    "majority_level",
    "mean_interval",
    "pair_trials",
    "pareto_front",
    "pixels_per_degree",
    "plot_cost_accuracy",
    "plot_metric_bars",
    "plot_pair_test",
    "plot_ramp_test",
    "plot_ring_errors",
    "plot_slider_test",
    "psnr",
    "ramp_trials",
    "read_csv",
    "read_responses",
    "run_study",
    "slider_trial",
    "ssim",
    "ssim_map",
    "study_trials",
    "wilson_interval",
    "write_csv",
    "write_responses",
    "write_study_report",
    "MAJORITY_TESTS",
    "STUDY_METRICS",
    "THESIS_LEVEL",
    "LevelDifference",
    "default_metric",
    "difference_from_comparison",
    "observers_from_comparison",
    "study_majorities",
    "VIDEO_GAZE_MODES",
    "StudySequence",
    "VideoStudy",
    "judge_sequence",
    "study_sequence",
    "sx111_display",
    "verdict_from_jods",
    "video_study",
    "FAILURE_CASES",
    "FITTED_MAR",
    "AcuityTerms",
    "EqualBudget",
    "FailureCase",
    "FailureReport",
    "acuity_models",
    "after_saccade",
    "checkerboard",
    "checkerboard_scene",
    "corner_gaze",
    "default_models",
    "equal_budget_foveations",
    "failure_cases",
    "high_spp",
    "offset_gaze",
    "scanpath_flicker",
    "tracking_error",
    "FLICKER_REGIONS",
    "KEY_MODES",
    "FullRenders",
    "StabilityResult",
    "flicker",
    "gaze_sequence",
    "region_masks",
    "temporal_stability",
    "plot_acuity_models",
    "plot_after_saccade",
    "plot_checkerboard",
    "plot_corner_gaze",
    "plot_flicker",
    "plot_high_spp",
    "plot_scanpath_flicker",
    "plot_tracking_error",
]

# `require_extra(module, extra, what)`: the imported module, or `MissingExtraError` naming the
# `pip install 'fovjax[extra]'` that provides it (for the commands that need an optional extra).
require_extra = _require
