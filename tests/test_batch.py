"""Batch layer: spec expansion (pure), results rows from real closed loops, crash safety,
resume and the Dask path.

Closed loops here are D2R2 CPT runs of 0.2 s (the first 20 % of the first cubic segment).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from robust_drake.batch import (METRIC_KEYS, ResultStore, clear_loop_cache, read_results,
                                run_batch, run_scenario)
from robust_drake.errors import RobustDrakeError
from robust_drake.scenario import (Scenario, expand_product, load_spec, spec_fingerprint,
                                   validate_scenarios)

REPO = pathlib.Path(__file__).resolve().parents[1]
SHORT = 0.2  # s of simulated time per closed loop


# ----------------------------------------------------------------------------- pure: specs


def test_product_expansion_is_the_cartesian_product():
    spec = {"robot": "d2r2", "trajectory": "cpt", "duration": SHORT,
            "controllers": ["pd", "sp1", "sp2"], "loads": ["none", "max"],
            "rates": [2500, 1000], "friction_compensation": [False, True], "seeds": [0, 1, 2]}
    scenarios = expand_product(spec)
    assert len(scenarios) == 3 * 2 * 2 * 2 * 3
    combos = {(s.controller, s.load, s.rate, s.friction_compensation, s.seed) for s in scenarios}
    expected = set(itertools.product(["pd", "sp1", "sp2"], ["none", "max"], [2500.0, 1000.0],
                                     [False, True], [0, 1, 2]))
    assert combos == expected  # every combination exactly once
    assert len({s.id for s in scenarios}) == len(scenarios)
    assert all(s.duration == SHORT and s.robot == "d2r2" for s in scenarios)
    validate_scenarios(scenarios)


def test_per_controller_params_and_labels():
    spec = {"controllers": ["sp1", {"name": "sp2", "params": {"epsilon": [0.1, 0.1, 0.1]},
                                    "label": "sp2-wide"}],
            "controller_params": {"sp1": {"epsilon": 0.05}}}
    s1, s2 = expand_product(spec)
    assert (s1.controller, s1.controller_params) == ("sp1", {"epsilon": 0.05})
    assert (s2.controller, s2.controller_params) == ("sp2", {"epsilon": [0.1, 0.1, 0.1]})
    assert s2.name.startswith("sp2-wide")
    # mapping form of the controllers axis
    a, b = expand_product({"controllers": {"pd": {}, "sp1": {"rho": 0.2}}})
    assert (a.controller, b.controller, b.controller_params) == ("pd", "sp1", {"rho": 0.2})


def test_ids_are_stable_and_fingerprint_ignores_order():
    assert Scenario(rate=2500).id == Scenario(rate=2500.0).id
    assert Scenario(controller_params={"rho": 1}).id == Scenario(controller_params={"rho": 1.0}).id
    assert Scenario(seed=1).id != Scenario(seed=2).id
    assert Scenario(label="a").id == Scenario(label="b").id  # labels are display only
    sc = expand_product({"controllers": ["pd", "sp1"], "loads": ["none", "max"]})
    assert spec_fingerprint(sc) == spec_fingerprint(sc[::-1])
    assert spec_fingerprint(sc) != spec_fingerprint(sc[:-1])


def test_spec_errors_are_user_errors():
    with pytest.raises(RobustDrakeError, match="unknown key 'controlers'"):
        expand_product({"controlers": ["sp1"]})
    with pytest.raises(RobustDrakeError) as exc:
        validate_scenarios([Scenario(controller="nope", load="heavy", rate=-1)])
    msg = str(exc.value)
    assert "unknown controller 'nope'" in msg and "sp1" in msg  # lists the known names
    assert "no load 'heavy'" in msg and "rate must be a positive" in msg


def test_yaml_list_and_csv_specs(tmp_path):
    y = tmp_path / "s.yaml"
    y.write_text("duration: 0.2\nscenarios:\n  - {controller: sp1, load: max}\n"
                 "  - {controller: pd}\n  - {controller: pd}\n")
    scenarios, _ = load_spec(y)
    assert [(s.controller, s.load, s.duration) for s in scenarios] == [
        ("sp1", "max", 0.2), ("pd", "none", 0.2)]  # the duplicate runs once
    c = tmp_path / "s.csv"
    c.write_text("controller,load,rate,friction_compensation,controller_params.epsilon,label\n"
                 "sp1,max,1000,yes,0.05,a\npd,none,2500,false,,b\n")
    scenarios, _ = load_spec(c)
    assert scenarios[0].controller_params == {"epsilon": 0.05}
    assert scenarios[0].friction_compensation is True and scenarios[0].rate == 1000.0
    assert scenarios[1].controller_params == {} and scenarios[1].friction_compensation is False
    # the shipped examples parse and validate
    for ex in sorted((REPO / "examples").glob("batch_*")):
        sc, _ = load_spec(ex)
        validate_scenarios(sc)
        assert len(sc) > 0


def test_scenario_to_config():
    s = Scenario(load="max", controller="sp2", rate=1000, friction=False,
                 friction_compensation=True, duration=0.3, true_theta=[0.7, 0.1, 0.08],
                 extra={"torque_limit": None, "metrics_skip": 0.1})
    c = s.to_config()
    assert (c.load, c.controller, c.rate, c.duration) == ("max", "sp2", 1000.0, 0.3)
    assert c.plant_friction is None and c.friction_compensation is True
    assert c.torque_limit is None and c.metrics_skip == 0.1
    assert c.true_theta == [0.7, 0.1, 0.08]
    with pytest.raises(RobustDrakeError, match="not a ClosedLoopConfig option"):
        Scenario(extra={"controller": "pd"}).to_config()


# ----------------------------------------------------------------------------- closed loops


def _scen(**kw):
    kw.setdefault("duration", SHORT)
    return Scenario(**kw)


@pytest.fixture(scope="module")
def small_batch():
    """PD and SP1 on the unloaded and the maximum-load D2R2, plus one broken scenario."""
    scenarios = [_scen(controller=c, load=l) for c in ("pd", "sp1") for l in ("none", "max")]
    scenarios.append(_scen(controller="sp1", controller_params={"no_such_gain": 1.0}))
    clear_loop_cache()
    return scenarios, run_batch(scenarios, workers=1, progress=False)


def test_rows_carry_physics(small_batch):
    scenarios, df = small_batch
    assert list(df["scenario_id"]) == [s.id for s in scenarios]
    ok = df[df["status"] == "ok"].set_index(["controller", "load"])
    assert len(ok) == 4
    for k in METRIC_KEYS:
        assert np.all(np.isfinite(ok[k])) and np.all(ok[k] >= 0)
    # Heavier load, same PD gains: larger tracking error (more inertia to accelerate).
    assert ok.loc[("pd", "max"), "maxerr_task"] > ok.loc[("pd", "none"), "maxerr_task"]
    # SP1's model-based feedforward beats PD on the loaded arm (JS section 9).
    assert ok.loc[("sp1", "max"), "maxerr_task"] < ok.loc[("pd", "max"), "maxerr_task"]
    # Torques: saturated at the D2R2 limit 31.2 N m; rms <= peak.
    for j in (1, 2):
        assert np.all(ok[f"tau_peak{j}"] <= 31.2 + 1e-9)
        assert np.all(ok[f"tau_rms{j}"] <= ok[f"tau_peak{j}"] + 1e-12)
        assert np.all(ok[f"tau_tv{j}"] > 0)
    # Task error bounded by the joint errors: |dp| <= l1 |e1| + l2 (|e1| + |e2|).
    bound = 0.3 * ok["maxerr1"] + 0.3 * (ok["maxerr1"] + ok["maxerr2"])
    assert np.all(ok["maxerr_task"] <= bound + 1e-12)
    assert np.all(np.abs(ok["sim_seconds"] - SHORT) < 1e-3)


def test_failing_scenario_is_recorded_and_others_continue(small_batch):
    _, df = small_batch
    bad = df[df["status"] == "failed"]
    assert len(bad) == 1
    assert "no_such_gain" in bad["error"].iloc[0]
    assert np.isnan(bad["maxerr_task"].iloc[0])


def test_divergence_is_detected():
    # High PD gains sampled at 200 Hz without a torque limit: the sampled-data loop is
    # unstable (K T / M >> 2) and |q| explodes within a few samples.
    s = _scen(controller="pd", controller_params={"K": [300.0, 300.0]}, rate=200.0,
              duration=0.5, extra={"torque_limit": None})
    row = run_scenario(s, reuse=False)
    assert row["status"] == "diverged", row["error"]
    assert "diverged" in row["error"] and row["sim_seconds"] < 0.5
    # The same gains at 2500 Hz are stable: it is the sampling, not the gains alone.
    ok = run_scenario(_scen(controller="pd", controller_params={"K": [300.0, 300.0]},
                            extra={"torque_limit": None}), reuse=False)
    assert ok["status"] == "ok", ok["error"]
    # A bounded run whose error exceeds the caller's limit counts as lost tracking.
    lost = run_scenario(_scen(controller="pd", load="max"), reuse=False,
                        divergence_error=0.5 * ok["maxerr1"])
    assert lost["status"] == "diverged" and "tracking lost" in lost["error"]


def test_reused_diagram_gives_the_same_run_as_a_fresh_build():
    from robust_drake.models import D2R2_THETA_LOADED

    clear_loop_cache()
    a = _scen(controller="sp2")
    b = _scen(controller="sp2", true_theta=list(D2R2_THETA_LOADED))
    run_scenario(a)  # builds and caches
    reused = run_scenario(b)
    fresh = run_scenario(b, reuse=False)
    assert reused["build_seconds"] == 0.0 and fresh["build_seconds"] > 0.0
    for k in METRIC_KEYS:
        assert reused[k] == pytest.approx(fresh[k], rel=1e-12, abs=1e-15)
    # and the true parameters mattered
    assert reused["maxerr2"] != pytest.approx(run_scenario(a)["maxerr2"], rel=1e-6)


# ----------------------------------------------------------------------------- files


def test_incremental_file_resume_and_fingerprint(tmp_path):
    out = tmp_path / "r.parquet"
    scenarios = [_scen(controller=c) for c in ("pd", "sp1", "sp2")]
    stop_after = 2

    def interrupt(row, seen=[]):
        seen.append(row)
        if len(seen) == stop_after:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch(scenarios, out=out, workers=1, progress=False, on_row=interrupt)
    saved = read_results(out)
    assert len(saved) == stop_after  # everything finished before Ctrl-C is on disk
    df = run_batch(scenarios, out=out, workers=1, progress=False)
    assert (df.attrs["ran"], df.attrs["skipped"]) == (1, 2)
    assert list(df["status"]) == ["ok"] * 3
    assert not out.with_name(out.name + ".parts").exists()  # merged into one file
    again = run_batch(scenarios, out=out, workers=1, progress=False)
    assert again.attrs["ran"] == 0
    pd.testing.assert_frame_equal(again[list(METRIC_KEYS)], df[list(METRIC_KEYS)])
    # another spec must not overwrite the file ... unless forced
    other = [_scen(controller="pd", load="max")]
    with pytest.raises(RobustDrakeError, match="different batch"):
        run_batch(other, out=out, workers=1, progress=False)
    assert len(read_results(out)) == 3
    forced = run_batch(other, out=out, workers=1, progress=False, force=True)
    assert forced.attrs["ran"] == 1 and len(read_results(out)) == 1


def test_killed_batch_process_loses_only_scenarios_in_flight(tmp_path):
    spec = tmp_path / "spec.yaml"
    # 0.5 s loops: slow enough that the kill lands mid-batch even on a fast machine
    spec.write_text("duration: 0.5\ncontrollers: [pd, sp1, sp2]\nloads: [none, max]\n")
    out = tmp_path / "k.parquet"
    parts = out.with_name(out.name + ".parts")
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen(
        [sys.executable, "-m", "robust_drake.cli", "batch", str(spec), "--out", str(out),
         "--workers", "1", "--no-progress"], cwd=tmp_path, env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(list(parts.glob("*.parquet"))) < 2:
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)  # no cleanup at all
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    n_saved = len(read_results(out))
    assert 2 <= n_saved < 6
    scenarios, doc = load_spec(spec)
    df = run_batch(scenarios, out=out, workers=1, progress=False, spec=doc)
    assert df.attrs["skipped"] == n_saved and df.attrs["ran"] == 6 - n_saved
    assert len(read_results(out)) == 6 and set(df["status"]) == {"ok"}


def test_cli_batch_json_with_two_workers(tmp_path, capsys):
    from robust_drake.cli import main

    spec = tmp_path / "spec.csv"
    spec.write_text("controller,load\npd,none\nsp1,max\nsp1,none\n")
    out = tmp_path / "c.parquet"
    status = main(["batch", str(spec), "--out", str(out), "--workers", "2",
                   "--duration", str(SHORT), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert status == 0
    assert doc["status_counts"] == {"ok": 3, "diverged": 0, "failed": 0}
    assert doc["ran"] == 3 and doc["scenarios"] == 3
    assert {r["controller"] for r in doc["summary"]} == {"pd", "sp1"}
    df = pd.read_parquet(out)
    assert len(df) == 3 and len(set(df["worker"])) >= 1
    assert not any(str(os.getpid()) == w.split(":")[-1] for w in df["worker"])  # not in-process
    # a user error: exit status 2, message, no traceback
    assert main(["batch", str(tmp_path / "missing.yaml"), "--out", str(out)]) == 2


def test_dask_local_cluster_matches_in_process():
    distributed = pytest.importorskip("distributed")
    scenarios = [_scen(controller=c, load=l) for c in ("pd", "sp2") for l in ("none", "max")]
    clear_loop_cache()
    local = run_batch(scenarios, workers=1, progress=False)
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=":0") as cluster:
        remote = run_batch(scenarios, scheduler=cluster.scheduler_address, progress=False)
        with distributed.Client(cluster) as client:
            worker_pids = set(client.run(os.getpid).values())
    assert list(remote["status"]) == ["ok"] * 4
    for k in METRIC_KEYS:  # same deterministic simulation wherever it runs
        np.testing.assert_allclose(remote[k], local[k], rtol=1e-12, atol=0)
    assert {int(w.split(":")[-1]) for w in remote["worker"]} <= worker_pids
