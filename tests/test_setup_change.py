"""Setup change between the fit run and the validation run (issue 21 item 6), the unpaired block
test behind it, and the URDF comparison over the identifiable directions (item 7).

The simulator (simulated.simulate_experiment) is the truth: a payload mounted or a torque sensor
re-zeroed only for the validation run must be flagged and no effect claimed; runs of the same arm
must be flagged at most at the stated rate; the exact URDF must not read as a significant shift,
a real payload must."""

import os

import numpy as np
import pytest
from scipy.signal import lfilter

from robust_drake.model_repair import stages as S
from robust_drake.model_repair.decisions import LEVEL, block_ids, block_length, unpaired_test
from robust_drake.model_repair.diagnostics import setup_change_of
from robust_drake.model_repair.nominal import compare_with_nominal
from robust_drake.model_repair.pipeline import RepairOptions, run_repair
from robust_drake.synthetic.simulated import DEFAULT_ROBOT, simulate_experiment

COULOMB = (0.02, 0.01)  # small: no sticking at reversals (simulated.hidden_effect_case)


def _ar1(rng, N, phi):
    return lfilter([1.0], [1.0, -phi], rng.standard_normal(N)) * np.sqrt(1.0 - phi**2)


@pytest.mark.parametrize("phi", [0.9, 0.98])
def test_unpaired_test_false_rates_on_independent_ar1_runs(phi):
    """Two independent AR(1) runs of different lengths, same variance: "worse" and "better" each
    at most 5 % over 300 seeds at the nominal one-sided 2.5 % (measured 4.0 / 2.75 % at phi 0.9,
    3.25 / 2.25 % at 0.98 over 400 seeds), and the interval covers no change >= 90 %."""
    L = block_length(1.0, -1.0 / np.log(phi))
    worse = better = cover = 0
    for s in range(300):
        rng = np.random.default_rng(s)
        a, c = _ar1(rng, 3000, phi), _ar1(rng, 5000, phi)
        t = unpaired_test(a**2, block_ids(None, 3000, L), c**2, block_ids(None, 5000, L))
        worse += t.worse
        better += t.better
        cover += t.low <= 0.0 <= t.high
    assert worse / 300 <= 0.05 and better / 300 <= 0.05, (worse, better)
    assert cover / 300 >= 0.90, cover


def test_unpaired_test_detects_a_larger_error_and_its_interval_covers_it():
    L = block_length(1.0, -1.0 / np.log(0.95))
    hits = cover = 0
    for s in range(100):
        rng = np.random.default_rng(s)
        a, c = _ar1(rng, 3000, 0.95), 1.3 * _ar1(rng, 5000, 0.95)  # validation RMS 30 % higher
        t = unpaired_test(a**2, block_ids(None, 3000, L), c**2, block_ids(None, 5000, L))
        hits += t.worse
        cover += t.low <= 0.3 <= t.high
        assert not t.better
    assert hits >= 85 and cover >= 85, (hits, cover)


def _runs(tmp, seed, val_effects=(), val_offset=None, duration=10.0):
    fit, val = os.path.join(tmp, f"fit{seed}.csv"), os.path.join(tmp, f"val{seed}.csv")
    simulate_experiment(DEFAULT_ROBOT, [], duration=duration, seed=seed, coulomb=COULOMB, out_csv=fit)
    df = simulate_experiment(DEFAULT_ROBOT, list(val_effects), duration=duration, seed=seed + 1, coulomb=COULOMB)
    for j, o in enumerate(val_offset or ()):
        df[f"tau{j + 1}"] += o  # the torque sensor re-zeroed between the runs
    df.to_csv(val, index=False)
    return fit, val


def _setup_change(fit, val):
    opts = RepairOptions(robot=DEFAULT_ROBOT)
    inp = S.load_inputs([fit], [val], opts, lambda m: None)
    base = S.fit_baseline(inp, opts, lambda m: None)
    return setup_change_of(inp.cf, base.weights, base.fit.residual, inp.val, base.val_residual), inp, base


def test_payload_only_in_validation_is_flagged_and_no_effect_claimed(tmp_path):
    fit, val = _runs(str(tmp_path), 0, [("payload", None, {"mass": 0.2, "robot": DEFAULT_ROBOT})])
    rep = run_repair([fit], RepairOptions(robot=DEFAULT_ROBOT, replay=False, plots=False), validate_paths=[val],
                     out_dir=str(tmp_path / "out"))
    sc = rep["setup_change"]
    assert sc["flagged"] and sc["joints"] == [0, 1]
    # a 0.2 kg tool mass moves the joint torques by far more than the 5 mN m noise: many times
    for t in sc["tests"]:
        assert t["ratio_low"] > 5.0, t
    assert rep["verdict"] == "no_improvement" and "does not match the fit run" in rep["verdict_reason"]
    assert all(not e["claimed"] for e in rep["effects"])
    assert rep["unexplained_structure"]
    warn = [w for w in rep["warnings"] if w.startswith("setup changed")]
    assert len(warn) == 1 and "joint 1 (" in warn[0] and "joint 2 (" in warn[0]
    assert "setup change" in open(tmp_path / "out" / "report.md").read()


def test_sensor_offset_change_between_runs_is_flagged_on_that_joint(tmp_path):
    # 0.03 N m on joint 1's torque only (6x the torque noise), nothing else differs
    sc, _, _ = _setup_change(*_runs(str(tmp_path), 3, val_offset=(0.0, 0.03)))
    assert sc["flagged"] and sc["joints"] == [1], sc["tests"]


def test_same_arm_runs_flagged_at_most_at_the_stated_rate(tmp_path):
    """No change between the runs, 10 seeds: flagged at most once (family-wise one-sided level
    (1 - LEVEL) / 2 = 2.5 %: P(>= 2 of 10) = 2.5 %). Measured 1 of 30 seeds (12 s runs,
    /tmp/diagnostics/null30.txt in the branch's report)."""
    flagged = []
    for seed in range(10):
        sc, _, _ = _setup_change(*_runs(str(tmp_path), 10 * seed, duration=8.0))
        flagged.append(sc["flagged"])
        assert sc["level"] == LEVEL
    assert sum(flagged) <= 1, flagged


def test_exact_urdf_is_not_a_significant_shift_and_a_payload_is(tmp_path):
    """The nominal comparison's chi^2 on the identifiable directions: the simulator's own URDF
    (no effect) over three seeds below the 99 % limit; a 0.2 kg payload in both runs above it."""
    for seed in (0, 1, 2):
        _, inp, base = _setup_change(*_runs(str(tmp_path), 20 + seed, duration=8.0))
        nom = compare_with_nominal(inp.cf, inp.cv, inp.regressor, base.fit, [], [], base.weights)
        assert not nom["significant"] and nom["chi2"] < nom["chi2_limit"], nom["chi2"]
    pay = [("payload", None, {"mass": 0.2, "robot": DEFAULT_ROBOT})]
    fit, val = os.path.join(tmp_path, "pf.csv"), os.path.join(tmp_path, "pv.csv")
    simulate_experiment(DEFAULT_ROBOT, pay, duration=8.0, seed=5, coulomb=COULOMB, out_csv=fit)
    simulate_experiment(DEFAULT_ROBOT, pay, duration=8.0, seed=6, coulomb=COULOMB, out_csv=val)
    _, inp, base = _setup_change(fit, val)
    nom = compare_with_nominal(inp.cf, inp.cv, inp.regressor, base.fit, [], [], base.weights)
    assert nom["significant"] and nom["chi2"] > nom["chi2_limit"]


def test_exact_urdf_with_unidentifiable_directions_is_not_significant(tmp_path):
    """serial7 whose last two joints move 2 mrad: six directions are unidentifiable. Over all 48
    base parameters the exact URDF read chi^2 163-262 against the 99 % limit 73.7 (measured on
    seeds 0-2 before issue 21); over the identifiable directions it must stay below the limit."""
    from robust_drake.synthetic.battery import _sim_kwargs

    kw = _sim_kwargs("serial7")
    kw["excitation"] = dict(kw["excitation"], amplitude=[0.6] * 5 + [0.002, 0.002])
    paths = [str(tmp_path / f"s{s}.csv") for s in (0, 1)]
    for s, p in enumerate(paths):
        simulate_experiment("serial7", [], duration=6.0, seed=s, out_csv=p, **kw)
    opts = RepairOptions(robot="serial7")
    inp = S.load_inputs(paths[:1], paths[1:], opts, lambda m: None)
    base = S.fit_baseline(inp, opts, lambda m: None)
    nom = compare_with_nominal(inp.cf, inp.cv, inp.regressor, base.fit, [], [], base.weights)
    assert base.fit.unidentifiable and nom["unidentified_directions"] > 0
    assert not nom["significant"] and nom["chi2"] < nom["chi2_limit"], (nom["chi2"], nom["chi2_all_parameters"])


@pytest.mark.slow
def test_an_effect_in_both_runs_is_not_a_setup_change(tmp_path):
    """A Stribeck hump (10x the noise, serial7 joint 2, 100 Hz) in both runs: the two motions excite
    it differently, so the BASELINE's validation error is beyond its held-out error (measured
    x2.9 [1.9, 4.4] on joint 2) and, before the re-check, the verdict was no_improvement with the
    right effect kept but not claimed. With the kept effect in both sides the mismatch is gone:
    not flagged, the effect claimed with its torque within 10 %."""
    from robust_drake.synthetic import arm_battery as AB

    fits, vals, truth = AB.library_case("serial7", "stribeck", 10.0, out_dir=str(tmp_path), rate_hz=100.0,
                                        duration=10.0, seed=200)
    rep = run_repair(fits, RepairOptions(robot=truth["fit_robot"], consistent=False, replay=False, plots=False),
                     validate_paths=vals, out_dir=str(tmp_path / "out"))
    sc = rep["setup_change"]
    assert truth["joint"] in sc.get("baseline_joints", []), sc["tests"]  # the baseline alone flags it
    assert not sc["flagged"] and not any(t["worse"] for t in sc["explained_by_effects"]["tests"])
    kept = [e for e in rep["effects"] if e["kind"] == "stribeck" and e["joint"] == truth["joint"]]
    assert kept and kept[0]["claimed"] and rep["verdict"] == "repaired"
    true = truth["parameters"]["stribeck_torque"]
    assert abs(kept[0]["parameters"]["stribeck_torque"] - true) <= 0.10 * true
    md = open(tmp_path / "out" / "report.md").read()
    assert "an effect the baseline lacks, not a changed setup" in md and "with the kept effects" in md
