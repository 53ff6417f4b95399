"""robust_drake.parallel: the same outcomes in-process, in a local process pool and on Dask.

Job functions are module-level so worker processes can import them by reference.
"""

from __future__ import annotations

import math
import os
import time

import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.parallel import RunOutcome, iter_parallel, run_parallel


def job_sqrt(x):
    """math.sqrt raises ValueError for x < 0: a genuine user-code failure."""
    return math.sqrt(x)


def job_pid(x):
    time.sleep(0.4)  # long enough for the second worker to start even on a busy machine
    return os.getpid()


def job_crash_on(x):
    """Simulates a segfault / kill -9 of the worker on item 'crash'."""
    if x == "crash":
        os._exit(3)
    time.sleep(0.05)
    return x


def job_sleep(x):
    time.sleep(x)
    return x


ITEMS = [4.0, 9.0, -1.0, 2.25]


def _check_sqrt_outcomes(outcomes):
    assert [o.key for o in outcomes] == list(range(len(ITEMS)))
    for o, x in zip(outcomes, ITEMS):
        assert isinstance(o, RunOutcome)
        if x >= 0:
            assert o.ok and o.error is None
            assert o.value == pytest.approx(math.sqrt(x))
            assert o.value**2 == pytest.approx(x)
        else:
            assert not o.ok and o.value is None
            assert o.error.startswith("ValueError: math domain error")
            assert "job_sqrt" in o.error  # innermost frame named in the summary
            assert "Traceback" in o.traceback
        assert o.wall_seconds >= 0.0


def test_serial_captures_errors_and_continues():
    outcomes = run_parallel(job_sqrt, ITEMS, workers=1, progress=False)
    _check_sqrt_outcomes(outcomes)


def test_serial_accepts_local_function_and_keys():
    # workers=1 never pickles, so a closure works; keys label the outcomes.
    offset = 10

    def local(x):
        return x + offset

    outcomes = run_parallel(local, [1, 2], keys=["a", "b"], workers=1, progress=False)
    assert [(o.key, o.value) for o in outcomes] == [("a", 11), ("b", 12)]


def test_process_pool_matches_math_and_uses_other_processes():
    outcomes = run_parallel(job_sqrt, ITEMS, workers=2, progress=False)
    _check_sqrt_outcomes(outcomes)
    pids = [o.value for o in run_parallel(job_pid, range(4), workers=2, progress=False)]
    assert os.getpid() not in pids
    assert len(set(pids)) == 2  # both workers did work


def test_killed_worker_loses_only_its_item():
    items = ["a", "b", "crash", "c", "d", "e"]
    outcomes = run_parallel(job_crash_on, items, workers=2, progress=False)
    by_key = {o.key: o for o in outcomes}
    assert len(outcomes) == len(items)
    assert not by_key[2].ok and "worker process died" in by_key[2].error
    for i, x in enumerate(items):
        if x != "crash":
            assert by_key[i].ok, by_key[i].error
            assert by_key[i].value == x


def test_stream_yields_in_completion_order():
    # Item 0 sleeps much longer than the others: with 2 workers it cannot come first.
    seen = [o.key for o in iter_parallel(job_sleep, [1.0, 0.01, 0.01, 0.01], workers=2,
                                         progress=False)]
    assert sorted(seen) == [0, 1, 2, 3]
    assert seen[-1] == 0


def test_unpicklable_function_is_a_user_error():
    with pytest.raises(RobustDrakeError, match="module-level function"):
        run_parallel(lambda x: x, [1, 2], workers=2, progress=False)


def test_bad_arguments():
    with pytest.raises(RobustDrakeError, match="keys"):
        run_parallel(job_sqrt, [1.0, 2.0], keys=["only-one"], workers=1)
    with pytest.raises(RobustDrakeError, match="workers"):
        run_parallel(job_sqrt, [1.0], workers=0)
    assert run_parallel(job_sqrt, [], workers=2) == []


def test_dask_local_cluster_client_and_address():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=":0") as cluster:
        # By address (what `--scheduler tcp://...` does): a client is opened and closed.
        outcomes = run_parallel(job_sqrt, ITEMS, scheduler=cluster.scheduler_address,
                                progress=False)
        _check_sqrt_outcomes(outcomes)
        # With an existing client; results computed in the cluster's worker processes.
        with distributed.Client(cluster) as client:
            pids = [o.value for o in run_parallel(job_pid, range(4), scheduler=client,
                                                  progress=False)]
            assert os.getpid() not in pids
            assert set(pids) <= set(client.run(os.getpid).values())


def test_long_tmpdir_falls_back_to_spawn(monkeypatch):
    """A TMPDIR too long for the fork server's AF_UNIX socket (108 bytes) would make the first
    pool fail with "AF_UNIX path too long": the context falls back to spawn."""
    import tempfile

    from robust_drake import parallel

    if parallel.START_METHOD != "forkserver":
        pytest.skip("no fork server on this platform")
    monkeypatch.setattr(tempfile, "tempdir", "/tmp/" + "x" * 90)
    assert not parallel.forkserver_socket_fits()
    assert parallel.mp_context().get_start_method() == "spawn"
    monkeypatch.setattr(tempfile, "tempdir", "/tmp")
    assert parallel.mp_context().get_start_method() == "forkserver"
