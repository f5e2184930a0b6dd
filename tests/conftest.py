"""Shared test set-up. The suite runs in two pytest-xdist workers (pyproject's addopts): on a
GPU each worker is its own JAX process, so neither may preallocate most of the device memory."""

import os

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
