"""benchmarks/trace_warp.py's "JAX" column is the JAX traversal: every ray query it makes names
`backend="jax"` (the default, "auto", is Warp itself on CUDA, so a query without it would time
Warp against Warp on a GPU)."""

import ast
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "trace_warp.py"


def test_every_query_of_the_jax_column_names_the_jax_backend():
    calls = [
        node
        for node in ast.walk(ast.parse(SCRIPT.read_text()))
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) in ("closest_hit", "occluded")
    ]
    assert len(calls) == 2  # closest_hit for primary and random rays, occluded for shadow rays
    for call in calls:
        backend = {k.arg: k.value for k in call.keywords}.get("backend")
        assert isinstance(backend, ast.Constant) and backend.value == "jax", (
            f"trace_warp.py:{call.lineno}: {call.func.id} without backend='jax'"  # type: ignore[attr-defined]
        )
