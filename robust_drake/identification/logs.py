"""Logs as a user holds them -> the CSV files identification reads.

Identification, repair and :meth:`IdentifiedModel.predict` read logs from files (the repair reloads
them, e.g. at the instruments' cut-off), so logs given in memory are written to canonical CSV
files in a temporary folder for the duration of the call (:func:`as_log_files`):

* a path, or a list of paths: CSV files (canonical ``t, q1..qn, tau1..taun`` or DFKI records);
* a numpy array (N, 1 + 2n): columns ``t, q1..qn, tau1..taun`` [s, rad, N m], in that order;
* a pandas DataFrame: its columns by name (canonical or DFKI names, as in a CSV file);
* a list of arrays / DataFrames: one file (a separate segment) each.

Anything else is refused with a one-line error naming what was given.
"""

from __future__ import annotations

import contextlib
import os
import tempfile

import numpy as np

from robust_drake.errors import RobustDrakeError

#: the column order of a log given as an array
ARRAY_COLUMNS = "t, q1..qn, tau1..taun"


def _kind(x) -> str:
    if isinstance(x, (str, os.PathLike)):
        return "path"
    if isinstance(x, np.ndarray):
        return "array"
    if type(x).__name__ == "DataFrame" and hasattr(x, "to_csv"):
        return "frame"
    return "other"


def _bad(what: str, x) -> RobustDrakeError:
    return RobustDrakeError(f"{what}: logs must be CSV paths, an array (N, 1 + 2n) with columns {ARRAY_COLUMNS}, "
                            f"or a pandas DataFrame (or a list of them); got {type(x).__name__}")


def _write_array(a: np.ndarray, n: int | None, path: str, what: str) -> None:
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] < 3 or (a.shape[1] - 1) % 2:
        raise RobustDrakeError(f"{what}: an array log must be (N, 1 + 2n) with columns {ARRAY_COLUMNS}; "
                               f"got shape {a.shape}")
    k = (a.shape[1] - 1) // 2
    if n is not None and k != n:
        raise RobustDrakeError(f"{what}: the array has {a.shape[1]} columns ({k} joints); this arm has {n} joints, "
                               f"so {1 + 2 * n} columns {ARRAY_COLUMNS}")
    header = ",".join(["t"] + [f"q{i + 1}" for i in range(k)] + [f"tau{i + 1}" for i in range(k)])
    np.savetxt(path, a, delimiter=",", header=header, comments="", fmt="%.17g")


@contextlib.contextmanager
def as_log_files(logs, n: int | None = None, what: str = "logs"):
    """Context manager yielding a list of CSV paths for ``logs`` (module docstring); in-memory
    logs are written to a temporary folder removed on exit. ``n``: the arm's joint count (checks
    an array's width)."""
    items = list(logs) if isinstance(logs, (list, tuple)) else [logs]
    if not items:
        raise RobustDrakeError(f"{what}: no logs given")
    kinds = [_kind(x) for x in items]
    for x, k in zip(items, kinds):
        if k == "other":
            raise _bad(what, x)
    if all(k == "path" for k in kinds):
        yield [os.fspath(x) for x in items]
        return
    with tempfile.TemporaryDirectory(prefix="robust_drake_logs_") as tmp:
        paths = []
        for i, (x, k) in enumerate(zip(items, kinds)):
            if k == "path":
                paths.append(os.fspath(x))
                continue
            path = os.path.join(tmp, f"{'array' if k == 'array' else 'dataframe'}{i}.csv")
            if k == "array":
                _write_array(x, n, path, what)
            else:
                x.to_csv(path, index=False, float_format="%.17g")
            paths.append(path)
        yield paths
