"""Shared test settings: short horizons for notebooks, Agg backend, repo paths."""

import os
import pathlib

import matplotlib

matplotlib.use("Agg")
os.environ.setdefault("ROBUST_DRAKE_SHORT", "1")

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
