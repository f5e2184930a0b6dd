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
    # jod_at(level): your FovVideoVDP JOD of that foveation level against the full render
    observer = fe.MetricObserver(lambda trial: 10 - jod_at(trial.level), threshold=fe.JND_JOD)
    fe.write_study_report(fe.run_study([observer]), "out/study")      # figures 66-68
"""

from ._charts import (
    plot_cost_accuracy,
    plot_metric_bars,
    plot_pair_test,
    plot_ramp_test,
    plot_ring_errors,
    plot_slider_test,
    write_study_report,
)
from ._compare import DEFAULT_CRITERION, DEFAULT_GAZES, Comparison, compare_thresholds
from ._metrics import (
    JND_JOD,
    HmdDisplay,
    MetricValue,
    MissingExtraError,
    RingErrors,
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

__all__ = [
    "DEFAULT_CRITERION",
    "DEFAULT_GAZES",
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
]
