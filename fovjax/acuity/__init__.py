"""Visual-acuity toolkit: data with provenance, models V(ω), fits with optimistix, uncertainty with
emcee or the bootstrap, model choice, and a stability sweep of the solvers.

    import fovjax.acuity as fa
    data = fa.load_csv("data/mandelbaum/curve_samples.csv")
    result = fa.fit(data, "exponential")          # Levenberg–Marquardt by default
    samples = fa.sample_posterior(data, "exponential", start=result)  # sampler=fa.EmceeOptions(...)
    fa.compare(data).chosen                       # simplest model within ΔAIC < 2 of the best
    model = fa.load_fit("fits/curve_samples.json")  # model(omega) works on float32 arrays under jit
"""

from ._compare import CandidateScore, Comparison, compare, leave_one_out
from ._data import (
    MAR_SCHEMA,
    SCHEMA,
    AcuityData,
    AcuityDataError,
    from_arrays,
    load_csv,
    mar_to_acuity,
    save_csv,
)
from ._fit import (
    SOLVERS,
    DivergenceError,
    FitError,
    FitResult,
    IdentifiabilityError,
    StalledError,
    StepLimitError,
    TooFewPointsError,
    fit,
)
from ._io import fit_record, load_fit, read_fit, save_fit
from ._models import MODEL_FAMILIES, THESIS_MODEL, AcuityModel, Exponential, LinearMAR, PowerMAR, model_family
from ._plot import plot_corner, plot_fit
from ._posterior import (
    EmceeOptions,
    PosteriorConvergenceError,
    PosteriorConvergenceWarning,
    Samples,
    bootstrap,
    sample_posterior,
)
from ._stability import SweepConfig, run_sweep, write_sweep

__all__ = [
    "MAR_SCHEMA",
    "MODEL_FAMILIES",
    "SCHEMA",
    "SOLVERS",
    "THESIS_MODEL",
    "AcuityData",
    "AcuityDataError",
    "AcuityModel",
    "CandidateScore",
    "Comparison",
    "DivergenceError",
    "EmceeOptions",
    "Exponential",
    "FitError",
    "FitResult",
    "IdentifiabilityError",
    "LinearMAR",
    "PosteriorConvergenceError",
    "PosteriorConvergenceWarning",
    "PowerMAR",
    "Samples",
    "StalledError",
    "StepLimitError",
    "SweepConfig",
    "TooFewPointsError",
    "bootstrap",
    "compare",
    "fit",
    "fit_record",
    "from_arrays",
    "leave_one_out",
    "load_csv",
    "load_fit",
    "mar_to_acuity",
    "model_family",
    "plot_corner",
    "plot_fit",
    "read_fit",
    "run_sweep",
    "sample_posterior",
    "save_csv",
    "save_fit",
    "write_sweep",
]
