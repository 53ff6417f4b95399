"""Run independent jobs (closed loops, identifications...) in parallel with a progress bar.

One helper, three back ends, the same results:

* ``workers=1``: in this process, one after the other (no pool; easiest to debug).
* ``workers=N`` (default ``os.cpu_count()``): a :class:`concurrent.futures.ProcessPoolExecutor`
  with the ``"forkserver"`` start method (``"spawn"`` where forkserver does not exist). Plain
  ``fork`` is avoided on purpose: pydrake starts threads and holds native state that a forked
  child may inherit half-initialised.
* ``scheduler="tcp://host:8786"`` or a ``distributed.Client``: Dask distributed
  (``client.submit`` + ``as_completed``). We never schedule anything ourselves.

Every item runs ``func(item)``; ``func`` must be a module-level (picklable) function and the
items picklable. An item whose ``func`` raises becomes ``RunOutcome(ok=False, error=...)``
and the others continue. A worker process that dies (segfault, ``kill -9``, out of memory)
costs only the items running on it at that moment: each of them is rerun alone on a fresh
pool, and the one that kills its worker again is recorded as failed. At most ``workers`` items are in flight, so a crash or
Ctrl-C loses at most those.

Orphans. Local workers exit when the process that started the pool dies, even by
``kill -9``: each worker arms ``prctl(PR_SET_PDEATHSIG, SIGTERM)`` (Linux; fires when its
parent dies) and runs a daemon watchdog thread that checks every
:data:`WATCHDOG_SECONDS` that the pool's owner is still alive (its parent under
``forkserver`` is the fork server, which itself only exits once every worker has closed its
copy of the fork server's "alive" pipe). The first worker to see its owner dead removes the
owner's multiprocessing temporary folder; the fork server and the resource tracker then
see end-of-file on their pipes and exit too.

>>> import math
>>> from robust_drake.parallel import run_parallel
>>> outcomes = run_parallel(math.sqrt, [1.0, 4.0, -1.0], workers=1, progress=False)
>>> [o.value for o in outcomes if o.ok]
[1.0, 2.0]

``run_parallel(..., stream=True)`` (or :func:`iter_parallel`) yields outcomes in completion
order, which is what a caller writing results incrementally wants.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import shutil
import signal
import sys
import threading
import time
import traceback
from collections import deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Sequence

from robust_drake.errors import RobustDrakeError

__all__ = ["RunOutcome", "run_parallel", "iter_parallel", "default_workers", "mp_context"]

#: Start method for local worker processes. "forkserver" is measurably cheaper than "spawn"
#: when the forkserver preloads pydrake (see BUILD_NOTES "Batch and Monte Carlo").
START_METHOD = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"

#: Modules imported once in the fork server so every worker starts with them loaded
#: (a failing import here is ignored by multiprocessing; the worker then imports lazily).
FORKSERVER_PRELOAD = ["numpy", "pydrake.all", "robust_drake.diagram"]


#: Seconds between two checks of a worker's watchdog that the pool's owner is alive.
WATCHDOG_SECONDS = 0.5

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _proc_start_time(pid: int):
    """Start time of ``pid`` (clock ticks since boot, /proc/PID/stat field 22), None if
    unknown; "dead" if the process is gone or a zombie."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read().decode(errors="replace")
    except FileNotFoundError:
        return "dead"
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 2:].split()  # after "pid (comm) "
    if not fields or fields[0] in ("Z", "X"):
        return "dead"
    return fields[19] if len(fields) > 19 else None


def _owner_alive(pid: int, start_time) -> bool:
    """Is the process ``pid`` that had ``start_time`` (see :func:`_proc_start_time`) alive?"""
    now = _proc_start_time(pid)
    if now == "dead":
        return False
    if now is not None:
        return start_time is None or now == start_time  # else: the pid was reused
    try:  # no /proc
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _set_parent_death_signal() -> None:
    """Linux: SIGTERM this process when its parent dies (no-op elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except Exception:  # pragma: no cover - the watchdog still covers it
        pass


def _watchdog(owner_pid: int, owner_start, parent_pid: int, tempdir: str | None) -> None:
    while True:
        time.sleep(WATCHDOG_SECONDS)
        if os.getppid() != parent_pid or not _owner_alive(owner_pid, owner_start):
            if tempdir and os.path.basename(tempdir).startswith("pymp-"):
                shutil.rmtree(tempdir, ignore_errors=True)
            os._exit(1)


def _worker_init(owner_pid: int, owner_start, tempdir: str | None) -> None:
    """Initializer of every local worker process: exit when the pool's owner dies."""
    try:
        parent = os.getppid()
        _set_parent_death_signal()
        if not _owner_alive(owner_pid, owner_start):
            os._exit(1)
        threading.Thread(target=_watchdog, args=(owner_pid, owner_start, parent, tempdir),
                         name="robust_drake-orphan-watchdog", daemon=True).start()
    except Exception:  # pragma: no cover - never break the pool over the watchdog
        pass


def _worker_initargs(ctx) -> tuple:
    """(owner pid, its start time, its multiprocessing temp folder if it has one)."""
    import multiprocessing.util as mp_util  # (a bare "import multiprocessing.util" here would
    # make the name multiprocessing local to this function)

    if ctx.get_start_method() == "forkserver":
        mp_util.get_temp_dir()  # the fork server's socket goes there anyway
    pid = os.getpid()
    start = _proc_start_time(pid)
    tempdir = multiprocessing.current_process()._config.get("tempdir")
    return pid, (None if start == "dead" else start), tempdir


@dataclass
class RunOutcome:
    """What happened to one item.

    ``error`` is a one-line summary ``"ExcType: message (at file.py:123 in func)"``;
    ``traceback`` holds the full formatted traceback (``None`` when ok).
    """

    key: Any
    ok: bool
    value: Any = None
    error: str | None = None
    wall_seconds: float = 0.0
    traceback: str | None = None


def default_workers() -> int:
    """Number of local worker processes used when ``workers`` is not given."""
    return max(1, os.cpu_count() or 1)


#: longest AF_UNIX socket path (Linux sun_path is 108 bytes with the terminating NUL)
AF_UNIX_PATH_MAX = 107


def forkserver_socket_fits() -> bool:
    """Does the fork server's listener socket (``TMPDIR/pymp-XXXXXXXX/listener-XXXXXXXX``) fit in
    an AF_UNIX address? With a long TMPDIR it does not, and the first pool would fail with
    "AF_UNIX path too long"; :func:`mp_context` then uses the spawn start method."""
    import tempfile

    return len(os.path.join(tempfile.gettempdir(), "pymp-xxxxxxxx", "listener-xxxxxxxx")) <= AF_UNIX_PATH_MAX


def mp_context(method: str | None = None):
    """The multiprocessing context for local pools (forkserver preloading pydrake, or spawn)."""
    method = method or START_METHOD
    if method == "forkserver" and not forkserver_socket_fits():
        method = "spawn"  # the fork server's AF_UNIX socket would not fit under TMPDIR
    ctx = multiprocessing.get_context(method)
    if method == "forkserver":
        # Only takes effect when the fork server starts (first pool in this process).
        ctx.set_forkserver_preload(FORKSERVER_PRELOAD)
    return ctx


def _summarise(exc: BaseException) -> tuple[str, str]:
    """(one-line summary with the innermost frame, full traceback text)."""
    tb = traceback.extract_tb(exc.__traceback__)
    where = ""
    if tb:
        frame = tb[-1]
        where = f" (at {os.path.basename(frame.filename)}:{frame.lineno} in {frame.name})"
    msg = str(exc).strip().splitlines()
    first = msg[0] if msg else ""
    if len(msg) > 1:
        first += " ..."
    full = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    return f"{type(exc).__name__}: {first}{where}", full


def _call(func: Callable, item: Any) -> tuple[bool, Any, str | None, str | None, float]:
    """Run ``func(item)`` and catch its exceptions (executed in the worker)."""
    t0 = time.perf_counter()
    try:
        value = func(item)
    except Exception as exc:  # noqa: BLE001 - reported, never swallowed silently
        summary, full = _summarise(exc)
        return False, None, summary, full, time.perf_counter() - t0
    return True, value, None, None, time.perf_counter() - t0


def _outcome(key, packed) -> RunOutcome:
    ok, value, error, tb, wall = packed
    return RunOutcome(key=key, ok=ok, value=value, error=error, wall_seconds=wall, traceback=tb)


def _failed(key, exc: BaseException, wall: float = 0.0) -> RunOutcome:
    summary, full = _summarise(exc)
    return RunOutcome(key=key, ok=False, error=summary, wall_seconds=wall, traceback=full)


def _make_bar(total: int, desc: str, progress: bool):
    """A tqdm bar on a terminal or in a notebook, an INFO log line every ~10 % (elapsed and
    remaining time) otherwise (:func:`robust_drake.log.progress_bar`); nothing when not ``progress``."""
    from robust_drake.log import progress_bar

    return progress_bar(total, desc, unit="runs", enabled=bool(progress))


def _check_picklable(func, items) -> None:
    try:
        pickle.dumps(func)
    except Exception as exc:
        raise RobustDrakeError(
            f"run_parallel: {func!r} cannot be sent to worker processes ({exc}); "
            "use a module-level function (not a lambda or a local function), or workers=1"
        ) from exc
    if items:
        try:
            pickle.dumps(items[0])
        except Exception as exc:
            raise RobustDrakeError(
                f"run_parallel: the items cannot be pickled ({exc}); pass plain data "
                "(dicts, dataclasses of numbers/strings/arrays), or workers=1"
            ) from exc


def iter_parallel(
    func: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    keys: Sequence[Any] | None = None,
    workers: int | None = None,
    desc: str = "runs",
    progress: bool = True,
    scheduler: Any = None,
    start_method: str | None = None,
) -> Iterator[RunOutcome]:
    """Yield a :class:`RunOutcome` for each item, in completion order.

    Parameters are those of :func:`run_parallel`. Breaking out of the loop (or Ctrl-C)
    cancels the items not started yet.
    """
    for _, outcome in _iter_indexed(func, items, keys, workers, desc, progress, scheduler,
                                    start_method):
        yield outcome


def run_parallel(
    func: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    keys: Sequence[Any] | None = None,
    workers: int | None = None,
    desc: str = "runs",
    progress: bool = True,
    scheduler: Any = None,
    stream: bool = False,
    start_method: str | None = None,
) -> list[RunOutcome] | Iterator[RunOutcome]:
    """Run ``func(item)`` for every item, in parallel; never raises because of one item.

    Parameters
    ----------
    func : module-level function of one argument (picklable).
    items : the arguments (picklable).
    keys : one label per item for the outcomes (default: the item's index).
    workers : local worker processes; default ``os.cpu_count()``; ``1`` runs in this process.
    desc : progress bar label.
    progress : show progress: a tqdm bar on a terminal or in a notebook, else a log line
        (``robust_drake`` logger, INFO) every ~10 % with the elapsed and remaining time.
    scheduler : ``None`` (local), a Dask scheduler address ``"tcp://host:port"`` or a
        ``distributed.Client``; then ``workers`` is ignored (the cluster decides).
    stream : if True return an iterator yielding outcomes as they complete; otherwise a list
        in the order of ``items``.
    start_method : override ``"forkserver"``/``"spawn"`` for the local pool.

    Returns
    -------
    list of :class:`RunOutcome` (input order) or an iterator (completion order).
    """
    if stream:
        return iter_parallel(func, items, keys=keys, workers=workers, desc=desc,
                             progress=progress, scheduler=scheduler, start_method=start_method)
    indexed = list(_iter_indexed(func, items, keys, workers, desc, progress, scheduler,
                                 start_method))
    indexed.sort(key=lambda pair: pair[0])
    return [outcome for _, outcome in indexed]


def _iter_indexed(func, items, keys, workers, desc, progress, scheduler, start_method):
    """Yield (input index, outcome) pairs in completion order, updating the progress bar."""
    items = list(items)
    if keys is None:
        keys = list(range(len(items)))
    else:
        keys = list(keys)
        if len(keys) != len(items):
            raise RobustDrakeError(f"run_parallel: {len(keys)} keys for {len(items)} items")
    if workers is not None and int(workers) < 1:
        raise RobustDrakeError(f"run_parallel: workers must be >= 1, got {workers}")
    if not items:
        return
    if scheduler is not None:
        source = _iter_dask(func, items, keys, scheduler)
    elif int(workers or default_workers()) == 1:
        source = _iter_serial(func, items, keys)
    else:
        source = _iter_pool(func, items, keys, int(workers or default_workers()), start_method)

    bar = _make_bar(len(items), desc, progress)
    failed = 0
    bar.set_postfix(failed=0, refresh=False)
    try:
        for i, outcome in source:
            if not outcome.ok:
                failed += 1
                bar.set_postfix(failed=failed, refresh=False)
            bar.update(1)
            yield i, outcome
    finally:
        source.close()
        bar.close()


# ---------------------------------------------------------------------------------------------
# back ends


def _iter_serial(func, items, keys) -> Iterator[RunOutcome]:
    for i, (key, item) in enumerate(zip(keys, items)):
        yield i, _outcome(key, _call(func, item))


def _submit(pool, func, items, queue: deque, in_flight: dict) -> bool:
    """Submit the next index of ``queue``; False (index put back) if the pool is broken."""
    i = queue.popleft()
    try:
        fut = pool.submit(_call, func, items[i])
    except BrokenProcessPool:
        queue.appendleft(i)
        return False
    in_flight[fut] = (i, time.perf_counter())
    return True


def _iter_pool(func, items, keys, workers, start_method) -> Iterator[RunOutcome]:
    _check_picklable(func, items)
    workers = min(workers, len(items))
    ctx = mp_context(start_method)
    pending = deque(range(len(items)))  # not started yet
    suspects: deque = deque()  # were in flight, with others, when a worker process died

    while pending or suspects:
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                   initializer=_worker_init, initargs=_worker_initargs(ctx))
        in_flight: dict = {}
        broken = False
        try:
            while pending or suspects or in_flight:
                if not broken:
                    if suspects:
                        # Rerun each suspect alone: the one that kills its worker again is
                        # the culprit; the innocent bystanders complete normally.
                        if not in_flight:
                            broken = not _submit(pool, func, items, suspects, in_flight)
                    else:
                        # Keep `workers` items in flight: a crash or Ctrl-C loses only those.
                        while pending and len(in_flight) < workers and not broken:
                            broken = not _submit(pool, func, items, pending, in_flight)
                if not in_flight:
                    break
                alone = len(in_flight) == 1
                done, _ = wait(list(in_flight), return_when=FIRST_COMPLETED)
                for fut in done:
                    i, t0 = in_flight.pop(fut)
                    try:
                        packed = fut.result()
                    except BrokenProcessPool as exc:
                        broken = True
                        if alone:
                            yield i, _failed(keys[i], RuntimeError(
                                f"worker process died while running this item ({exc})"),
                                time.perf_counter() - t0)
                        else:
                            suspects.append(i)
                        continue
                    except Exception as exc:  # e.g. a result that cannot be pickled
                        yield i, _failed(keys[i], exc, time.perf_counter() - t0)
                        continue
                    yield i, _outcome(keys[i], packed)
                if broken and not in_flight:
                    break
        finally:
            # Normal end, Ctrl-C or the consumer stopped iterating: start nothing new.
            pool.shutdown(wait=not broken and not in_flight, cancel_futures=True)


def _iter_dask(func, items, keys, scheduler) -> Iterator[RunOutcome]:
    from robust_drake.extras import import_extra

    distributed = import_extra("distributed", "dask", "a Dask scheduler (batch --scheduler)")
    Client, as_completed = distributed.Client, distributed.as_completed

    own_client = False
    if isinstance(scheduler, str):
        try:
            client = Client(scheduler, timeout="20s")
        except Exception as exc:
            raise RobustDrakeError(
                f"cannot connect to the Dask scheduler at {scheduler!r}: {exc}") from exc
        own_client = True
    elif isinstance(scheduler, Client):
        client = scheduler
    else:
        raise RobustDrakeError(
            f"scheduler must be an address like 'tcp://host:8786' or a distributed.Client, "
            f"got {type(scheduler).__name__}")
    _check_picklable(func, items)
    futures = {}
    try:
        for i, item in enumerate(items):
            fut = client.submit(_call, func, item, pure=False)
            futures[fut] = i
        started = time.perf_counter()
        for fut in as_completed(list(futures)):
            i = futures.pop(fut)
            try:
                packed = fut.result()
            except Exception as exc:  # KilledWorker, CancelledError, ...
                yield i, _failed(keys[i], exc, time.perf_counter() - started)
            else:
                yield i, _outcome(keys[i], packed)
            fut.release()
    finally:
        if futures:
            client.cancel(list(futures))
        if own_client:
            client.close()
