"""Issue 11 (simulation side): runaway sizes, one divergence definition, strict JSON, input
validation, writes only under --out, the batch lock and no orphan processes."""

from __future__ import annotations

import glob
import json
import math
import os
import pathlib
import shutil
import tempfile
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from robust_drake.cli import main, print_json
from robust_drake.divergence import TRACKING_ERROR_LIMIT, is_diverged
from robust_drake.errors import RobustDrakeError

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _strict_loads(text: str):
    def refuse(name):
        raise ValueError(f"non-strict JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = REPO + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


# ----------------------------------------------------------------------------- runaway size


def test_too_large_rate_is_refused_before_anything_is_allocated():
    from robust_drake.diagram import MAX_LOG_SAMPLES, ClosedLoopConfig, simulate

    t0 = time.perf_counter()
    with pytest.raises(RobustDrakeError, match="MAX_LOG_SAMPLES") as exc:
        simulate(ClosedLoopConfig(duration=0.2, rate=1e9))
    # a regression guard against the 24 GB run, not a benchmark
    assert time.perf_counter() - t0 < 5.0
    assert "2e+08" in str(exc.value) and f"{MAX_LOG_SAMPLES:.3g}" in str(exc.value)
    # the trajectory's own duration (cpt: 2 s) is checked before the reference is tabulated
    with pytest.raises(RobustDrakeError, match="controller ticks"):
        simulate(ClosedLoopConfig(rate=5e6))
    # a slow loop over a long time: few ticks, but too many integrator steps
    with pytest.raises(RobustDrakeError, match="MAX_INTEGRATOR_STEPS"):
        simulate(ClosedLoopConfig(rate=1.0, duration=1e6))


def test_cli_refuses_the_runaway_rate_with_a_one_line_error(capsys):
    assert main(["simulate", "--duration", "0.2", "--rate", "1e9"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


# ----------------------------------------------------------------------------- divergence


def test_is_diverged_criteria():
    t = np.arange(10) * 0.1
    q_d = np.zeros((10, 2))
    q = np.full((10, 2), 0.01)
    v = np.zeros((10, 2))
    assert is_diverged(t, q, v, q_d) == (False, None)
    # just below half a turn of error: still tracking
    q_near = q.copy()
    q_near[5, 1] = 0.99 * TRACKING_ERROR_LIMIT
    assert not is_diverged(t, q_near, v, q_d)[0]
    # beyond it: tracking lost, from t = 0.6 s
    q_lost = q.copy()
    q_lost[6:, 0] = 4.0
    d, reason = is_diverged(t, q_lost, v, q_d)
    assert d and "tracking lost" in reason and "t = 0.6 s" in reason
    assert not is_diverged(t, q_lost, v, q_d, error_limit=None)[0]
    # non-finite state (from t = 0.3 s) wins over every other criterion
    v_nan = v.copy()
    v_nan[3:, 1] = np.nan
    d, reason = is_diverged(t, q_lost, v_nan, q_d)
    assert d and "non-finite" in reason and "t = 0.3 s" in reason
    # a state bound, even with zero tracking error
    v_fast = v.copy()
    v_fast[8, 0] = 2e3
    d, reason = is_diverged(t, q, v_fast, q_d)
    assert d and "|v|" in reason and "t = 0.8 s" in reason


def test_simulate_marks_a_lost_loop_diverged_and_keeps_the_reason():
    from robust_drake.diagram import ClosedLoopConfig, simulate

    # PD sampled at 5 Hz: the joint 2 error grows to ~22 rad (issue 11)
    res = simulate(ClosedLoopConfig(controller="pd", rate=5.0))
    assert res.diverged
    assert res.divergence_reason.startswith("tracking lost")
    assert np.max(np.abs(res.q - res.q_d)) > math.pi  # the logs really lost the reference
    assert all(math.isnan(v) for v in res.metrics.values())
    # the same PD at the paper's rate tracks
    ok = simulate(ClosedLoopConfig(controller="pd", duration=0.5))
    assert not ok.diverged and ok.divergence_reason is None
    assert ok.metrics["maxerr1"] < 0.1


def test_integrator_failure_keeps_its_message():
    from robust_drake.diagram import ClosedLoopConfig, simulate

    # high PD gains sampled at 200 Hz, no torque limit: |q| explodes within a few samples
    res = simulate(ClosedLoopConfig(controller="pd", controller_params={"K": [300.0, 300.0]},
                                    rate=200.0, duration=0.5, torque_limit=None))
    assert res.diverged and res.sim_seconds < 0.5
    # Drake's own message is kept (it used to be caught and dropped), then the state bound
    assert res.divergence_reason.startswith("simulation failed at t = ")
    assert "NaN" in res.divergence_reason and "rad/s beyond the limit" in res.divergence_reason


def test_batch_counts_a_1hz_loop_as_diverged_and_keeps_it_out_of_the_percentiles():
    from robust_drake.batch import run_batch, summarize
    from robust_drake.scenario import Scenario

    good = Scenario(controller="sp1", duration=0.5)
    slow = Scenario(controller="sp1", rate=5.0)  # 10 ticks on the 2 s CPT (at 1 Hz: 2, refused, issue 24)
    df = run_batch([good, slow], workers=1, progress=False)
    rows = {r["rate"]: r for r in df.to_dict("records")}
    assert rows[2500.0]["status"] == "ok"
    assert rows[5.0]["status"] == "diverged" and "tracking lost" in rows[5.0]["error"]
    assert math.isnan(rows[5.0]["maxerr_task"])
    s = summarize(df).iloc[0]
    assert (s["ok"], s["diverged"]) == (1, 1)
    assert s["worst"] == pytest.approx(rows[2500.0]["maxerr_task"])


# ----------------------------------------------------------------------------- strict JSON


def test_print_json_writes_strict_json(capsys):
    print_json({"a": float("nan"), "b": [np.float64("inf"), -math.inf, 1.5],
                "c": np.array([np.nan, 2.0]), "d": np.int64(3), "e": (1, None)})
    doc = _strict_loads(capsys.readouterr().out)
    assert doc == {"a": None, "b": [None, None, 1.5], "c": [None, 2.0], "d": 3, "e": [1, None]}


def _write(path, text):
    path.write_text(textwrap.dedent(text))
    return str(path)


@pytest.mark.parametrize("argv", [
    ["simulate", "--rate", "5"],
    ["compare", "--table", "2", "--controllers", "sp1", "--rate", "5", "--workers", "1"],
    ["sweep-rate", "--controllers", "sp1", "--rates", "5", "--duration", "2", "--workers", "1"],
    ["batch", "{spec}", "--out", "{tmp}/b.parquet", "--workers", "1", "--no-progress"],
    ["montecarlo", "--controllers", "sp1", "--draws", "1", "--rate", "5", "--workers", "1",
     "--out", "{tmp}/mc/x.parquet", "--no-progress"],
], ids=["simulate", "compare", "sweep-rate", "batch", "montecarlo"])
def test_every_simulation_command_prints_strict_json_for_a_diverged_run(argv, tmp_path, capsys):
    spec = _write(tmp_path / "spec.yaml", """
        controllers: [sp1]
        rates: [5.0]
        """)
    argv = [a.format(spec=spec, tmp=tmp_path) for a in argv] + ["--json"]
    main(argv)
    out = capsys.readouterr().out
    doc = _strict_loads(out)
    text = json.dumps(doc)
    # each document reports the 5 Hz run (10 ticks of the 2 s CPT; 1 Hz is refused, issue 24) as diverged (and its metrics as null, not NaN)
    assert ("diverged" in text) and ("null" in text)


# ----------------------------------------------------------------------------- validation


@pytest.mark.parametrize("kwargs, message", [
    (dict(duration="0.1"), "duration"),
    (dict(duration=float("nan")), "duration"),
    (dict(robot=123), "robot"),
    (dict(initial_q=[float("nan"), 0.0]), "initial_q"),
    (dict(metrics_dt=0), "metrics_dt"),
    (dict(metrics_dt=-0.01), "metrics_dt"),
    (dict(metrics_skip=-5), "metrics_skip"),
    (dict(rate=0), "rate"),
    (dict(rate=-2500.0), "rate"),
    (dict(rate="2500"), "rate"),
    (dict(controller_params=[1, 2]), "controller_params"),
    (dict(torque_limit=[31.2, -1.0]), "torque_limit"),
])
def test_bad_configs_are_refused_on_construction(kwargs, message):
    from robust_drake.diagram import ClosedLoopConfig

    with pytest.raises(RobustDrakeError, match=message):
        ClosedLoopConfig(**kwargs)


def test_unknown_controller_parameter_is_a_user_error():
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

    with pytest.raises(RobustDrakeError, match="nonsense"):
        build_closed_loop(ClosedLoopConfig(controller_params={"nonsense": 1}, duration=0.1))


def test_error_criteria_refuses_a_non_positive_dt():
    from robust_drake.metrics import error_criteria

    t = np.linspace(0, 1, 11)
    q = np.zeros((11, 2))
    with pytest.raises(RobustDrakeError, match="dt"):
        error_criteria(t, q + 0.1, q, dt=-0.01)
    with pytest.raises(RobustDrakeError, match="dt"):
        error_criteria(t, q + 0.1, q, dt=0.0)


def test_yaml_spec_of_integers_is_refused(tmp_path):
    from robust_drake.scenario import load_spec

    with pytest.raises(RobustDrakeError, match="scenario #1 must be a mapping"):
        load_spec(_write(tmp_path / "ints.yaml", "[1, 2, 3]\n"))


@pytest.mark.parametrize("argv", [
    ["simulate", "--plot", ""],
    ["batch", "{spec}", "--out", ""],
    ["montecarlo", "--out", ""],
    ["montecarlo", "--plot", " "],
])
def test_empty_output_paths_are_refused(argv, tmp_path, capsys):
    spec = _write(tmp_path / "spec.yaml", "controllers: [sp1]\n")
    assert main([a.format(spec=spec) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "empty" in err


# ----------------------------------------------------------------------------- files


def test_montecarlo_writes_only_under_the_folder_of_out(tmp_path, monkeypatch, capsys):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    out = tmp_path / "study" / "x.parquet"
    assert main(["montecarlo", "--controllers", "sp1", "--draws", "1", "--duration", "0.1",
                 "--workers", "1", "--no-progress", "--out", str(out)]) == 0
    capsys.readouterr()
    assert list(cwd.iterdir()) == []
    assert sorted(p.name for p in out.parent.iterdir()) == ["x.parquet", "x_maxerr_task.png"]


# ----------------------------------------------------------------------------- concurrency


def test_second_batch_on_the_same_file_is_refused_naming_the_holder(tmp_path):
    from robust_drake.batch import run_batch
    from robust_drake.scenario import Scenario

    out = tmp_path / "r.parquet"
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, pathlib; from robust_drake.batch import BatchLock; "
         f"lock = BatchLock(pathlib.Path({str(out)!r})); print('locked', flush=True); "
         "sys.stdin.readline()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=_env())
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(RobustDrakeError, match=f"PID {holder.pid}"):
            run_batch([Scenario(duration=0.05)], out=out, workers=1, progress=False)
        assert not out.exists()  # refused before anything ran or was written
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
    # once the other run has ended the file is free again
    df = run_batch([Scenario(duration=0.05)], out=out, workers=1, progress=False)
    assert list(df["status"]) == ["ok"] and out.exists()
    assert not out.with_name(out.name + ".lock").exists()


def _children(pid: int) -> set[int]:
    """Descendants of ``pid`` (read from /proc)."""
    parent_of = {}
    for stat in glob.glob("/proc/[0-9]*/stat"):
        try:
            with open(stat, "rb") as fh:
                text = fh.read().decode(errors="replace")
        except OSError:
            continue
        fields = text[text.rfind(")") + 2:].split()
        if fields and fields[0] != "Z":
            parent_of[int(stat.split("/")[2])] = int(fields[1])
    out, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, pp in parent_of.items() if pp in frontier} - out
        out |= frontier
    return out


def _alive(pids) -> set[int]:
    left = set()
    for p in pids:
        try:
            with open(f"/proc/{p}/stat", "rb") as fh:
                text = fh.read().decode(errors="replace")
        except OSError:
            continue
        if text[text.rfind(")") + 2:].split()[0] != "Z":
            left.add(p)
    return left


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc (Linux)")
def test_killed_batch_parent_leaves_no_process_behind(tmp_path):
    spec = _write(tmp_path / "spec.yaml", """
        controllers: [pd, sp1]
        duration: 3.0
        seeds: [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19]
        """)
    # the batch's multiprocessing temporary folders go here; a short path, since the fork server's
    # AF_UNIX socket lives in it (108-byte limit; pytest's tmp_path under xdist is longer)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="rdk", dir="/tmp"))
    parent = subprocess.Popen(
        [sys.executable, "-m", "robust_drake.cli", "batch", spec, "--out",
         str(tmp_path / "r.parquet"), "--workers", "2", "--no-progress"],
        stdout=subprocess.DEVNULL, stderr=open(tmp_path / "stderr.txt", "w"), env={**_env(), "TMPDIR": str(tmp)})
    kids: set[int] = set()
    try:
        deadline = time.monotonic() + 60
        # resource tracker + fork server + 2 workers
        while time.monotonic() < deadline and len(kids) < 4 and parent.poll() is None:
            kids |= _children(parent.pid)
            time.sleep(0.1)
        assert len(kids) >= 4 and parent.poll() is None, (
            f"the batch did not start its workers (children {sorted(kids)}, exit {parent.poll()}): "
            + (tmp_path / "stderr.txt").read_text()[-2000:])
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while _alive(kids) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _alive(kids) == set()
        assert list(tmp.iterdir()) == []
    finally:
        for p in _alive(kids):  # only the processes this test started
            os.kill(p, signal.SIGKILL)
        if parent.poll() is None:
            parent.kill()
        shutil.rmtree(tmp, ignore_errors=True)


def test_batch_refuses_a_runaway_scenario_before_running_anything(tmp_path):
    from robust_drake.batch import run_batch
    from robust_drake.scenario import Scenario

    out = tmp_path / "r.parquet"
    with pytest.raises(RobustDrakeError, match="MAX_LOG_SAMPLES"):
        run_batch([Scenario(duration=0.05), Scenario(duration=0.2, rate=1e9)], out=out,
                  workers=1, progress=False)
    assert not out.exists()
    with pytest.raises(RobustDrakeError, match="divergence_error"):
        run_batch([Scenario(duration=0.05)], workers=1, progress=False, divergence_error=-1.0)


def test_batch_runs_under_a_tmpdir_too_long_for_the_fork_server(tmp_path):
    """The fork server's AF_UNIX socket does not fit under a ~100-character TMPDIR; the batch
    falls back to spawn and runs (it used to fail with "AF_UNIX path too long")."""
    spec = _write(tmp_path / "spec.yaml", """
        controllers: [pd]
        duration: 0.2
        seeds: [0, 1]
        """)
    long_tmp = pathlib.Path(tempfile.mkdtemp(prefix="rdk" + "x" * 90, dir="/tmp"))
    try:
        out = subprocess.run(
            [sys.executable, "-m", "robust_drake.cli", "batch", spec, "--out", str(tmp_path / "r.parquet"),
             "--workers", "2", "--no-progress", "--json"],
            capture_output=True, text=True, timeout=300, env={**_env(), "TMPDIR": str(long_tmp)})
        assert out.returncode == 0, out.stderr[-2000:]
        assert "Traceback" not in out.stderr
    finally:
        shutil.rmtree(long_tmp, ignore_errors=True)
