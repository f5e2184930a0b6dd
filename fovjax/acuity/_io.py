"""Fit records on disk: `fits/NAME.json`, and loading one straight into a model.

The JSON holds the model name and parameters, intervals (Laplace and, when run, posterior),
metrics, the solver, the data file's path and SHA-256, package versions and the command that
produced it. `load_fit(path)` returns the model object; the foveation code calls it and then
evaluates `model(omega)` on float32 JAX arrays under jit.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import platform
from pathlib import Path

import numpy as np

from ._fit import FitResult
from ._models import AcuityModel, model_family
from ._posterior import Samples

SCHEMA_ID = "fovjax.acuity.fit/1"
_PACKAGES = (
    "fovjax",
    "jax",
    "jaxlib",
    "optimistix",
    "equinox",
    "lineax",
    "emcee",
    "numpy",
    "scipy",
    "matplotlib",
)


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _clean(x):
    # JSON has no inf/NaN: write them as null.
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def fit_record(
    result: FitResult,
    samples: Samples | None = None,
    comparison: dict | None = None,
    command: str | None = None,
) -> dict:
    family = result.family
    data = result.data
    record = {
        "schema": SCHEMA_ID,
        "model": family.name,
        "formula": family.formula,
        "params": result.params,
        "fixed": result.fixed,
        "units": dict(zip(family.param_names, family.units, strict=True)),
        "laplace": {
            "level": result.level,
            "stderr": {k: v for k, v in result.stderr.items() if k not in result.fixed},
            "intervals": {k: list(v) for k, v in result.intervals().items() if k not in result.fixed},
            "intervals_log_space": {
                k: list(v) for k, v in result.intervals(space="log").items() if k not in result.fixed
            },
            "covariance": result.covariance.tolist(),
            "covariance_order": list(family.param_names),
            "quantile": result.quantile(),
        },
        "metrics": result.metrics,
        "solver": {
            "name": result.solver,
            "result": result.result,
            "iterations": result.iterations,
            "start": result.start,
            "jacobian_condition": result.jacobian_condition,
            **result.extras,
        },
        "data": {
            "path": data.where,
            "sha256": data.sha256,
            "n": len(data),
            "condition": data.conditions[0] if data.conditions else "",
            "weighted": data.weighted,
        },
        "versions": package_versions(),
        "command": command,
    }
    if samples is not None:
        record["posterior"] = {
            "method": samples.method,
            "level": samples.level,
            "median": samples.median,
            "intervals": {k: list(v) for k, v in samples.intervals().items()},
            "diagnostics": samples.diagnostics,
        }
    if comparison is not None:
        record["comparison"] = comparison
    cleaned = _clean(record)
    assert isinstance(cleaned, dict)  # _clean maps a dict to a dict
    return cleaned


def save_fit(path: str | Path, record: dict) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2, ensure_ascii=False, allow_nan=False) + "\n")
    return path


def read_fit(path: str | Path) -> dict:
    """The fit record as a dict, after checking its schema."""
    path = Path(path)
    try:
        record = json.loads(path.read_text())
    except OSError as err:
        raise ValueError(f"{path}: cannot read fit record ({err.strerror})") from None
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}:{err.lineno}: not valid JSON ({err.msg})") from None
    if record.get("schema") != SCHEMA_ID:
        raise ValueError(f"{path}: schema is {record.get('schema')!r}, expected {SCHEMA_ID!r}")
    for key in ("model", "params"):
        if key not in record:
            raise ValueError(f"{path}: fit record has no {key!r} field")
    return record


def load_fit(path: str | Path, estimate: str = "fit") -> AcuityModel:
    """The model recorded in a fit JSON, ready to call on eccentricities: `load_fit(p)(omega)`.

    `estimate="fit"` uses the least-squares parameters; `"posterior_median"` the posterior
    medians (fixed parameters unchanged) when the record has a posterior.
    """
    record = read_fit(path)
    family = model_family(record["model"])
    params = dict(record["params"])
    if estimate == "posterior_median":
        if "posterior" not in record:
            raise ValueError(f"{path}: no posterior in this fit record (run `fovjax fit --posterior`)")
        params.update(record["posterior"]["median"])
    elif estimate != "fit":
        raise ValueError(f"estimate must be 'fit' or 'posterior_median', not {estimate!r}")
    try:
        return family.from_params(params)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
