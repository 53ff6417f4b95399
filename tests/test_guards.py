"""The never-worse guards decided by paired block tests (stages.Rule on decisions.py, issue 21).

Simulated DFKI C.1 arm (Drake plant, PD-tracked Fourier motion, 14-bit encoder, 5 mN m torque
noise), 12 s runs at 250 Hz, fit and validation on different motions:

* ``spring0``: a spring of 0.15 N m/rad on joint 0, in the fit AND the validation run. The model
  with spring[0] is really better on joint 0 and changes joint 1 only by the refit of shared
  parameters (noise): the guard keeps it, and the interval it reports on joint 0 lies below 0.
* ``fit-only spring1``: the fit run also has a spring on joint 1 (0.3 N m/rad) that the
  validation run does not have (a setup change between the runs): the model with spring[1] is
  truly worse on joint 1 on the validation data and is dropped, with a reason naming joint 1,
  the change with its interval and the level; spring[0] stays.
* the baseline's replay ("before") is computed once per repair however many attempts the replay
  guard makes (counted with monkeypatch).
* report.json carries the intervals (``final.validate_change``, ``never_worse.tests``,
  ``replay.after.tests``) and report.md prints them.
"""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from robust_drake.model_repair import stages as S
from robust_drake.effects import make_effect
from robust_drake.synthetic.simulated import DEFAULT_ROBOT, simulate_experiment

COULOMB = (0.02, 0.01)  # small Coulomb levels (simulated.hidden_effect_case: no sticking artefacts)


def _sim(path, springs, seed):
    effects = [("spring", j, {"stiffness": k}) for j, k in springs]
    simulate_experiment(DEFAULT_ROBOT, effects, duration=12.0, seed=seed, out_csv=str(path), coulomb=COULOMB)
    return str(path)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("guards")
    return {"fit0": _sim(d / "fit0.csv", [(0, 0.15)], 0), "val0": _sim(d / "val0.csv", [(0, 0.15)], 1),
            "fit01": _sim(d / "fit01.csv", [(0, 0.15), (1, 0.3)], 0), "dir": d}


def _opts(**kw):
    from robust_drake.model_repair.pipeline import RepairOptions

    return RepairOptions(robot=DEFAULT_ROBOT, plots=False, **kw)


def _stages(fit, val, effects, opts):
    log = lambda *_: None  # noqa: E731
    inp = S.load_inputs([fit], [val], opts, log)
    base = S.fit_baseline(inp, opts, log)
    steps = [SimpleNamespace(accepted=True, label=S.effect_label(e), gain=0.3, confirm_gain=0.3) for e in effects]
    sel = S.Selection([], steps, [], list(effects), base.weights, {S.effect_label(e): S.effect_label(e) for e in effects})
    return inp, base, S.Estimator(), sel, log


def test_a_model_better_on_one_joint_is_kept(runs):
    opts = _opts(consistent=False, replay=False)
    inp, base, est, sel, log = _stages(runs["fit0"], runs["val0"], [make_effect("spring", 0)], opts)
    est, sel, guard = S.never_worse(inp, base, est, sel, opts, log)
    assert [S.effect_label(e) for e in sel.chosen] == [S.effect_label(make_effect("spring", 0))]
    assert not guard.dropped
    t0, t1 = guard.tests
    # the spring's torque (0.15 N m/rad x rad-scale motion) is many times the 5 mN m noise: joint 0's
    # validation error falls, and the interval says so
    assert t0.better and t0.high < 0 and t0.low <= t0.estimate <= t0.high
    # joint 1 has no effect: whatever the refit moves there is not called worse
    assert not t1.worse
    assert t0.blocks >= 4 and t0.level == pytest.approx(0.95)
    # the blocks come from the baseline's validation residual, once: BLOCK_CORRELATIONS correlation
    # times plus the 8 Hz Butterworth's settling time, in samples of the 250 Hz log
    b = base.blocks
    want = (S.D.BLOCK_CORRELATIONS * b.correlation_time_s + b.settling_time_s) * 250.0
    assert b.block == max(1, min(round(want), inp.val.N // 4))


def test_b_a_model_truly_worse_on_one_joint_is_dropped(runs):
    opts = _opts(consistent=False, replay=False)
    effects = [make_effect("spring", 0), make_effect("spring", 1)]
    inp, base, est, sel, log = _stages(runs["fit01"], runs["val0"], effects, opts)
    est, sel, guard = S.never_worse(inp, base, est, sel, opts, log)
    labels = [S.effect_label(e) for e in sel.chosen]
    assert labels == [S.effect_label(effects[0])], labels  # the fit-only spring goes, the real one stays
    (d,) = guard.dropped
    assert d["label"] == S.effect_label(effects[1]) and d["joint"] == 1
    # the reason names the joint, the change with its interval and the level
    assert "joint(s) 2 (" in d["reason"] and "%" in d["reason"] and "[" in d["reason"] and "95%" in d["reason"]
    first = guard.attempts[0]["tests"][1]
    assert first["worse"] and first["low"] > 0.01  # worse beyond the 1 % margin and its own spread
    assert not any(t.worse for t in guard.tests)


def test_c_baseline_replay_is_computed_once(runs, monkeypatch):
    opts = _opts(consistent=True, replay=True, replay_windows=8)
    effects = [make_effect("spring", 0), make_effect("torque_offset", 1)]
    inp, base, est, sel, log = _stages(runs["fit0"], runs["val0"], effects, opts)
    guard = S.Guard(0.01)
    calls = []
    real_model = S.replay_model
    monkeypatch.setattr(S, "replay_model", lambda *a, **k: calls.append(a[3] is base.fit) or real_model(*a, **k))
    real_tests = S.replay_tests
    forced = []

    def tests_forcing_one_drop(*args):  # the first attempt is called worse on joint 1
        out = real_tests(*args)
        if not forced:
            forced.append(1)
            out[1] = S.replace(out[1], worse=True)
        return out

    monkeypatch.setattr(S, "replay_tests", tests_forcing_one_drop)
    est, sel, fin, cons, rp = S.replay_guard(inp, base, est, sel, guard, opts, log)
    assert len(guard.replay_attempts) == 2
    # the drop is the effect acting on the worse joint (torque_offset on joint 1), not simply the last
    assert guard.dropped[0]["joint"] == 1 and [e.joint for e in sel.chosen] == [0]
    assert calls.count(True) == 1 and calls.count(False) == 2, calls  # before once, after per attempt
    assert rp["before"]["rms_q"] and "error_q" not in rp["before"] and "tests" in rp["after"]


def test_d_report_carries_the_intervals(runs):
    from robust_drake.model_repair.pipeline import run_repair

    out = runs["dir"] / "report"
    run_repair([runs["fit0"]], _opts(kinds=["spring"], consistent=False, replay_windows=8, nominal=False),
               validate_paths=[runs["val0"]], out_dir=str(out))
    rep = json.loads((out / "report.json").read_text())
    assert [e["label"] for e in rep["effects"]] == [S.effect_label(make_effect("spring", 0))]
    ch = rep["final"]["validate_change"]
    assert len(ch) == 2 and all(t["level"] == 0.95 and t["blocks"] >= 4 for t in ch)
    base, final = np.array(rep["baseline"]["rms_validate"]), np.array(rep["final"]["rms_validate"])
    for j, t in enumerate(ch):
        assert t["low"] <= t["estimate"] <= t["high"]
        # the RMS change itself (block means of nearly equal blocks: the last block may be up to 1.5x long)
        assert t["estimate"] == pytest.approx(final[j] / base[j] - 1, abs=0.01)
    assert ch[0]["better"] and ch[0]["high"] < 0
    nw = rep["never_worse"]
    assert len(nw["tests"]) == 2 and nw["level"] == 0.95 and nw["blocks"]["block_samples"] >= 1
    assert len(rep["replay"]["after"]["tests"]) == 2 and set(rep["replay"]) == {"before", "after"}
    assert len(rep["effects"][0]["validate_change"]) == 2
    md = (out / "report.md").read_text()
    t = ch[0]
    assert f"joint 1 ({rep['joint_names'][0]}): {100 * t['estimate']:+.1f} % [{100 * t['low']:+.1f}, " in md
