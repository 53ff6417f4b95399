"""Shared test settings: short horizons for notebooks, Agg backend, repo paths."""

import os

# Before numpy loads: OpenBLAS threads make the many small LAPACK calls of identification
# thousands of times slower on a busy 2-core machine (measured; see BUILD_NOTES.md).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
import pathlib

import matplotlib

matplotlib.use("Agg")
os.environ.setdefault("ROBUST_DRAKE_SHORT", "1")

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
