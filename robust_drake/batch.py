"""Batch runs of closed loops: local worker processes or Dask, results that survive crashes.

:func:`run_batch` runs a list of :class:`~robust_drake.scenario.Scenario` through
:func:`robust_drake.parallel.iter_parallel` and writes one row per scenario to Parquet as
each finishes. Each row holds the scenario's parameters, the six JS error criteria
(eqs. 55, 56, 58, 59: ``error1, maxerr1, error2, maxerr2, error_task, maxerr_task``), torque
statistics per joint (``tau_peak<i>``, ``tau_rms<i>``, ``tau_tv<i>`` = total variation per
second), ``wall_seconds``, ``cpu_seconds`` (this process's CPU time: on a shared machine
``wall_seconds`` grows with the load, ``cpu_seconds`` does not), ``build_seconds``, ``status`` (``ok`` / ``diverged`` / ``failed``)
and ``error`` (the message, for failed or diverged runs).

Crash safety. Every finished row is written at once to its own small Parquet file in
``<out>.parts/`` (write to a temporary name, then an atomic rename); the single file
``<out>`` is rewritten from those parts every ``flush_seconds`` and at the end (also after
Ctrl-C), after which the parts are removed. A crash, a Ctrl-C or a killed worker loses at most
the scenarios in flight. Rerunning the same batch skips the scenarios already recorded
(``retry_failed=True`` reruns the failed ones). The file's metadata carries the batch
fingerprint (:func:`robust_drake.scenario.spec_fingerprint`); a results file of a different
batch is never overwritten unless ``force=True``.

Diagram reuse. A worker keeps the last few built diagrams keyed by
:meth:`Scenario.structure_key`; scenarios that differ only in ``true_theta``, ``duration``,
``initial_q`` or ``seed`` (Monte Carlo draws, repeated seeds) reuse the diagram with a fresh
context each run, so they pay the build cost once per worker.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import pathlib
import re
import shutil
import socket
import sys
import time
import uuid
from collections import OrderedDict
from typing import Any, Iterable, Sequence

from robust_drake.divergence import TRACKING_ERROR_LIMIT
from robust_drake.errors import RobustDrakeError, option_name
from robust_drake.parallel import iter_parallel
from robust_drake.scenario import Scenario, dedupe, spec_fingerprint, validate_scenarios

__all__ = [
    "METRIC_KEYS",
    "STATUSES",
    "run_batch",
    "run_scenario",
    "ResultStore",
    "read_results",
    "summarize",
]

METRIC_KEYS = ("error1", "maxerr1", "error2", "maxerr2", "error_task", "maxerr_task")
STATUSES = ("ok", "diverged", "failed")

#: A run whose joint error exceeds this [rad] has lost the reference: status "diverged"
#: (the shared definition is :func:`robust_drake.divergence.is_diverged`).
DEFAULT_DIVERGENCE_ERROR = TRACKING_ERROR_LIMIT

_META_KEY = b"robust_drake.batch"
_DICT_COLUMNS = ("controller_params", "trajectory_params", "observer_params", "tags", "extra")

# ------------------------------------------------------------------------------- worker side

_LOOPS: "OrderedDict[str, Any]" = OrderedDict()
_MAX_CACHED_LOOPS = 8


def clear_loop_cache() -> None:
    """Forget the diagrams this process has built (tests, memory)."""
    _LOOPS.clear()


def _get_loop(scenario: Scenario, config, reuse: bool):
    """(ClosedLoop, build_seconds); built diagrams are reused for equal structure keys."""
    from robust_drake.diagram import build_closed_loop

    key = scenario.structure_key()
    if reuse and key in _LOOPS:
        _LOOPS.move_to_end(key)
        loop = _LOOPS[key]
        fresh = config.resolved()
        # Per-run fields that ClosedLoop.simulate reads from its config.
        for name in ("true_theta", "initial_q", "duration", "metrics_skip", "metrics_dt",
                     "plant_setup", "divergence_error"):
            if hasattr(fresh, name):
                setattr(loop.config, name, getattr(fresh, name))
        return loop, 0.0
    t0 = time.perf_counter()
    loop = build_closed_loop(config)
    if hasattr(loop, "_finish"):  # Diagram.Build() happens lazily; count it as build time
        loop._finish()
    build = time.perf_counter() - t0
    if reuse:
        _LOOPS[key] = loop
        while len(_LOOPS) > _MAX_CACHED_LOOPS:
            _LOOPS.popitem(last=False)
    return loop, build


def _torque_columns(torque_stats: dict) -> dict:
    out = {}
    for src, dst in (("tau_peak", "tau_peak"), ("tau_rms", "tau_rms"), ("tau_tv_per_s", "tau_tv")):
        vals = torque_stats.get(src)
        if vals is None:
            continue
        for j, v in enumerate(vals):
            out[f"{dst}{j + 1}"] = float(v)
    return out


def run_scenario(scenario: Scenario | dict, *, reuse: bool = True,
                 divergence_error: float = DEFAULT_DIVERGENCE_ERROR) -> dict:
    """Run one scenario in this process and return its result row (never raises for a
    failing or diverging simulation; the row says so)."""
    if isinstance(scenario, dict):
        scenario = Scenario.from_dict(scenario)
    row = scenario_columns(scenario)
    row.update({k: math.nan for k in METRIC_KEYS})
    row.update(status="failed", error=None, build_seconds=0.0, sim_seconds=0.0,
               worker=f"{socket.gethostname()}:{os.getpid()}")
    t0 = time.perf_counter()
    c0 = time.process_time()
    try:
        config = scenario.to_config()
        loop, build = _get_loop(scenario, config, reuse)
        row["build_seconds"] = build
        loop.config.divergence_error = float(divergence_error)
        res = loop.simulate(None if scenario.duration is None else float(scenario.duration))
        row.update({k: float(res.metrics.get(k, math.nan)) for k in METRIC_KEYS})
        joints = {k: float(v) for k, v in res.metrics.items() if re.fullmatch(r"(max)?err(or)?\d+", k)}
        row.update(joints)  # every joint's criteria (METRIC_KEYS name the 2-link ones)
        maxerrs = [v for k, v in joints.items() if k.startswith("maxerr")]
        row["maxerr_joints"] = max(maxerrs) if maxerrs else math.nan  # defined on every arm [rad]
        row.update(_torque_columns(res.torque_stats or {}))
        row["sim_seconds"] = float(res.sim_seconds)
        if res.diverged:  # robust_drake.divergence.is_diverged, applied by ClosedLoop.simulate
            row["status"] = "diverged"
            row["error"] = f"diverged: {res.divergence_reason}"
            row.update({k: math.nan for k in row if k in METRIC_KEYS or re.fullmatch(r"(max)?err(or)?\d+|maxerr_joints", k)})  # never in percentiles
        else:
            row["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - recorded in the row, the batch continues
        from robust_drake.parallel import _summarise

        row["status"] = "failed"
        row["error"] = _summarise(exc)[0]
    row["wall_seconds"] = time.perf_counter() - t0
    row["cpu_seconds"] = time.process_time() - c0
    row["finished_at"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    return row


def _task(item: tuple) -> dict:
    """Worker entry point (module level so it pickles): item = (scenario dict, options)."""
    scenario_dict, options = item
    return run_scenario(scenario_dict, **options)


def scenario_columns(s: Scenario) -> dict:
    """The parameter columns of a result row (dicts as JSON text)."""
    d = s.to_dict()
    row = {"scenario_id": s.id, "name": s.name}
    for k, v in d.items():
        if k in _DICT_COLUMNS:
            row[k] = json.dumps(v, sort_keys=True)
        elif k == "true_theta":
            row[k] = None if v is None else [float(x) for x in v]
        else:
            row[k] = v
    row["rate"] = float(row["rate"])
    row["duration"] = math.nan if row["duration"] is None else float(row["duration"])
    row["draw"] = -1 if row["draw"] is None else int(row["draw"])
    return row


def _failed_row(s: Scenario, error: str, wall: float) -> dict:
    row = scenario_columns(s)
    row.update({k: math.nan for k in METRIC_KEYS})
    row.update(status="failed", error=error, build_seconds=0.0, sim_seconds=0.0,
               wall_seconds=float(wall), worker=None,
               finished_at=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    return row


# ------------------------------------------------------------------------------- storage


def _rows_frame(rows: list[dict]):
    import pandas as pd

    df = pd.DataFrame(rows)
    if "true_theta" in df:
        df["true_theta"] = df["true_theta"].astype(object)
    return df


class BatchLock:
    """Exclusive, non-blocking lock of one results file: ``fcntl.flock`` on ``<out>.lock``
    (holding this run's PID) for the whole run, so that a second batch on the same file is
    refused at once instead of rerunning every scenario beside the first. Released by
    :meth:`release` or when the process dies (the kernel drops flocks of dead processes).
    Where ``fcntl`` does not exist (Windows) no lock is taken."""

    def __init__(self, results_path: pathlib.Path):
        self.path = results_path.with_name(results_path.name + ".lock")
        self._fd = None
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                try:
                    other = os.read(fd, 64).decode(errors="replace").strip() or "unknown"
                finally:
                    os.close(fd)
                raise RobustDrakeError(
                    f"{results_path} is in use by another batch run (PID {other}, lock "
                    f"{self.path}); wait for it to finish or choose another results file (out)") from None
            # The holder before us may have unlinked the file after we opened it: lock again
            # on the file that is now at the path.
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self._fd = fd

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)  # while still holding it (see __init__)
        finally:
            os.close(self._fd)  # closes the flock too
            self._fd = None


class ResultStore:
    """Incremental, crash-safe Parquet results for one batch (see the module docstring).

    Holds a :class:`BatchLock` on the file from construction to :meth:`close`."""

    def __init__(self, path: str | os.PathLike, fingerprint: str, spec: Any = None,
                 force: bool = False):
        self.path = pathlib.Path(path)
        if self.path.suffix != ".parquet":
            raise RobustDrakeError(f"results file must end in .parquet (got {self.path})")
        self.lock = BatchLock(self.path)
        try:
            self._open(fingerprint, spec, force)
        except BaseException:
            self.lock.release()
            raise

    def close(self) -> None:
        """Release the lock on the results file."""
        lock = getattr(self, "lock", None)
        if lock is not None:
            lock.release()

    def _open(self, fingerprint: str, spec: Any, force: bool) -> None:
        self.parts = self.path.with_name(self.path.name + ".parts")
        self.fingerprint = fingerprint
        self.spec = spec
        self._last_flush = time.monotonic()
        existing = self._existing_fingerprint()
        if existing is not None and existing != fingerprint:
            if not force:
                raise RobustDrakeError(
                    f"{self.path} holds results of a different batch (fingerprint {existing}, "
                    f"this batch {fingerprint}); choose another {option_name('--out', 'out= file')} or pass "
                    f"{option_name('--force', 'force=True')} to overwrite it")
        if force:  # start over, whatever the file held
            self._remove_all()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.parts.mkdir(exist_ok=True)
        (self.parts / "_batch.json").write_text(json.dumps(
            {"fingerprint": fingerprint, "spec": spec}, default=str))

    # -- reading
    def _existing_fingerprint(self) -> str | None:
        fps = []
        if self.path.exists():
            fps.append(_file_fingerprint(self.path))
        meta = self.parts / "_batch.json"
        if meta.exists():
            try:
                fps.append(json.loads(meta.read_text()).get("fingerprint"))
            except Exception:  # a torn write: treat as unknown
                fps.append("unreadable")
        fps = [f for f in fps if f is not None]
        if not fps:
            return None
        return fps[0]

    def read(self):
        """All rows recorded so far (main file + parts), last row per scenario."""
        import pandas as pd
        import pyarrow.parquet as pq

        frames = []
        if self.path.exists():
            frames.append(pq.read_table(self.path).to_pandas())
        if self.parts.exists():
            for f in sorted(self.parts.glob("*.parquet")):
                try:
                    frames.append(pq.read_table(f).to_pandas())
                except Exception:  # pragma: no cover - a torn part cannot exist (rename)
                    continue
        if not frames:
            return pd.DataFrame()
        df = pd.concat(frames, ignore_index=True, sort=False)
        return df.drop_duplicates("scenario_id", keep="last").reset_index(drop=True)

    # -- writing
    def append(self, row: dict) -> None:
        """Persist one finished row now (atomic small file)."""
        name = f"{time.time_ns():020d}-{row['scenario_id']}-{uuid.uuid4().hex[:6]}.parquet"
        _write_parquet(_rows_frame([row]), self.parts / name, self._metadata())

    def maybe_flush(self, every: float) -> None:
        if time.monotonic() - self._last_flush >= every:
            self.flush()

    def flush(self, final: bool = False) -> None:
        """Rewrite the single results file from file + parts; drop the merged parts."""
        parts = sorted(self.parts.glob("*.parquet")) if self.parts.exists() else []
        df = self.read()
        if len(df):
            _write_parquet(df, self.path, self._metadata())
        for f in parts:
            f.unlink(missing_ok=True)
        if final and self.parts.exists():
            shutil.rmtree(self.parts, ignore_errors=True)
        self._last_flush = time.monotonic()

    def _metadata(self) -> dict:
        return {_META_KEY: json.dumps({"fingerprint": self.fingerprint, "spec": self.spec},
                                      default=str).encode()}

    def _remove_all(self) -> None:
        if self.path.exists():
            self.path.unlink()
        if self.parts.exists():
            shutil.rmtree(self.parts)


def _write_parquet(df, path: pathlib.Path, metadata: dict) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(df, preserve_index=False)
    meta = dict(table.schema.metadata or {})
    meta.update(metadata)
    table = table.replace_schema_metadata(meta)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        pq.write_table(table, tmp)
        os.replace(tmp, path)
    except BaseException:  # disk full, ulimit -f: no torn temporary file left beside the results
        tmp.unlink(missing_ok=True)
        raise


def _file_fingerprint(path: pathlib.Path) -> str | None:
    import pyarrow.parquet as pq

    try:
        meta = pq.read_schema(path).metadata or {}
    except Exception:
        return "not-a-robust-drake-results-file"
    raw = meta.get(_META_KEY)
    if raw is None:
        return "not-a-robust-drake-results-file"
    return json.loads(raw).get("fingerprint")


def read_results(path: str | os.PathLike):
    """Read a results file (and any parts of an interrupted run) as a DataFrame."""
    path = pathlib.Path(path)
    if not path.exists() and not path.with_name(path.name + ".parts").exists():
        raise RobustDrakeError(f"no results at {path}")
    store = ResultStore.__new__(ResultStore)
    store.path, store.parts = path, path.with_name(path.name + ".parts")
    return store.read()


# ------------------------------------------------------------------------------- the batch


def _done_rows(store, retry_failed: bool) -> dict[str, dict]:
    """Rows already in ``store`` that this run skips, by scenario id (``failed`` ones too
    unless ``retry_failed``). Closes the store if it cannot be read."""
    import pandas as pd

    try:
        previous = store.read() if store is not None else pd.DataFrame()
    except BaseException:
        store.close()
        raise
    done_rows: dict[str, dict] = {}
    if len(previous):
        skip_status = {"ok", "diverged"} if retry_failed else set(STATUSES)
        for rec in previous.to_dict("records"):
            if rec.get("status") in skip_status:
                done_rows[rec["scenario_id"]] = rec
    return done_rows


def _run_todo(todo: list[Scenario], options: dict, new_rows: dict[str, dict], store, *, workers,
              scheduler, progress: "bool | str", flush_seconds: float, on_row) -> None:
    """Run ``todo`` in parallel; each row goes into ``new_rows`` (filled in place, so the caller
    sees the rows done before an interrupt), the store and ``on_row`` as it arrives."""
    by_id = {s.id: s for s in todo}
    items = [(s.to_dict(), options) for s in todo]
    for outcome in iter_parallel(_task, items, keys=[s.id for s in todo], workers=workers,
                                 scheduler=scheduler, desc=progress if isinstance(progress, str) else "batch",
                                 progress=bool(progress)):
        if outcome.ok:
            row = outcome.value
        else:  # the worker died or the task could not run at all
            row = _failed_row(by_id[outcome.key], outcome.error, outcome.wall_seconds)
        new_rows[row["scenario_id"]] = row
        if store is not None:
            store.append(row)
            store.maybe_flush(flush_seconds)
        if on_row is not None:
            on_row(row)


def run_batch(
    scenarios: Iterable[Scenario | dict],
    *,
    out: str | os.PathLike | None = None,
    workers: int | None = None,
    scheduler: Any = None,
    force: bool = False,
    retry_failed: bool = False,
    progress: "bool | str" = True,
    reuse: bool = True,
    divergence_error: float = DEFAULT_DIVERGENCE_ERROR,
    spec: Any = None,
    flush_seconds: float = 10.0,
    validate: bool = True,
    on_row=None,
):
    """Run every scenario (in parallel) and return a pandas DataFrame, one row each.

    Parameters
    ----------
    scenarios : Scenario objects or dicts of Scenario fields. Duplicates run once.
    out : Parquet results file; written incrementally, resumed on rerun (None: memory only).
    workers : local worker processes (default: the core count; 1 runs in this process).
    scheduler : Dask scheduler address ``"tcp://host:8786"`` or a ``distributed.Client``.
    force : overwrite ``out`` even if it holds another batch's results.
    retry_failed : rerun scenarios recorded as ``failed`` (``diverged`` ones are results).
    reuse : reuse built diagrams within a worker for scenarios of equal structure.
    divergence_error : joint error [rad] beyond which a run counts as diverged.
    spec : the spec document to record in the file's metadata (the CLI passes the YAML).
    on_row : optional callback ``f(row_dict)`` called in this process for each new row.
    progress : True: a bar on a terminal or in a notebook, else a log line every ~10 % (a string
        labels it, e.g. ``"montecarlo"``); False: none.

    Returns
    -------
    DataFrame in the order of ``scenarios`` (rows found in ``out`` included). Attributes
    ``df.attrs["ran"]``, ``df.attrs["skipped"]``, ``df.attrs["fingerprint"]``.
    """
    import pandas as pd

    if not (isinstance(divergence_error, (int, float)) and math.isfinite(divergence_error)
            and divergence_error > 0):
        raise RobustDrakeError(f"divergence_error must be a positive number of rad (got {divergence_error!r})")
    scenarios = dedupe(s if isinstance(s, Scenario) else Scenario.from_dict(s) for s in scenarios)
    if validate:
        validate_scenarios(scenarios)
    fingerprint = spec_fingerprint(scenarios)
    store = ResultStore(out, fingerprint, spec, force=force) if out is not None else None
    done_rows = _done_rows(store, retry_failed)
    todo = [s for s in scenarios if s.id not in done_rows]
    options = {"reuse": reuse, "divergence_error": float(divergence_error)}
    new_rows: dict[str, dict] = {}
    t0 = time.perf_counter()
    try:
        if todo:
            _run_todo(todo, options, new_rows, store, workers=workers, scheduler=scheduler,
                      progress=progress, flush_seconds=flush_seconds, on_row=on_row)
    finally:
        if store is not None:
            pending = sys.exc_info()[1]  # an error already on its way out, if any
            try:  # every finished row goes into <out>; the parts are removed only once it holds them
                store.flush(final=True)
            except OSError:
                if pending is None:
                    raise
                # an error is already on its way (e.g. the disk filled up while writing a part): the
                # parts stay for the next run, which resumes from them
            finally:
                store.close()
    rows = []
    for s in scenarios:
        r = new_rows.get(s.id) or done_rows.get(s.id)
        if r is not None:
            rows.append(r)
    df = _rows_frame(rows) if rows else pd.DataFrame()
    df.attrs.update(ran=len(new_rows), skipped=len(scenarios) - len(todo),
                    fingerprint=fingerprint, wall_seconds=time.perf_counter() - t0)
    return df


def summarize(df, by: Sequence[str] = ("controller",), metric: str = "maxerr_task"):
    """Per-group counts by status and percentiles/worst of ``metric`` over ok runs."""
    import numpy as np
    import pandas as pd

    if df is None or len(df) == 0:
        return pd.DataFrame()
    by = [b for b in by if b in df.columns]
    out = []
    for key, g in df.groupby(by, sort=True, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        ok = g[g["status"] == "ok"][metric].astype(float).dropna()
        rec = dict(zip(by, key))
        rec.update(runs=len(g), ok=int((g["status"] == "ok").sum()),
                   diverged=int((g["status"] == "diverged").sum()),
                   failed=int((g["status"] == "failed").sum()))
        if len(ok):
            rec.update({"p50": float(np.percentile(ok, 50)), "p90": float(np.percentile(ok, 90)),
                        "p99": float(np.percentile(ok, 99)), "worst": float(ok.max())})
        else:
            rec.update(p50=math.nan, p90=math.nan, p99=math.nan, worst=math.nan)
        out.append(rec)
    return pd.DataFrame(out)
