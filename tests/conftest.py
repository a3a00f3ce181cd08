"""Test-session set-up shared by all test files."""

import os

# Small matrices: single-threaded BLAS is faster and keeps timings stable on 2 shared cores
# (the CLI does the same). Must run before NumPy is imported.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MPLBACKEND", "Agg")
