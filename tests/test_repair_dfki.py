"""The whole repair loop on real DFKI data (C.1 and A.0) and on the built-in simulated demo.

Real data: fit on the C.1 open-loop runs, validate on the closed-loop swing-ups (which move far
outside the fitting range), with the command's defaults (``tau_meas``, 8 Hz). What the loop
finds there is not a missing torque term but noise in the regressor: positions differentiated
twice carry encoder noise, least squares on noisy columns shrinks the parameters (the fitted
parameters fall as the cut-off rises, tested below), the Hausman test flags it and the
instrumental-variable estimate (instruments.py) removes it; the swing-ups' torque and the replayed
motion are then predicted better on both joints. The same command, with A.0's own URDF and no
validation files, runs unchanged on design A.0.
"""

import glob
import json
import os

import numpy as np
import pytest

from robust_drake import cli
from robust_drake.effects import EFFECTS

DFKI = os.path.join(os.environ.get("ROBUST_DRAKE_DATA")
                    or os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"), "dfki_double_pendulum")
C1 = os.path.join(DFKI, "design_C1")
A0 = os.path.join(DFKI, "design_A0")
needs_data = pytest.mark.skipif(not os.path.isdir(C1), reason="shared DFKI data not available")

CONTRACT = {"robot", "samples", "baseline", "effects", "final", "unexplained_structure", "replay"}


def _check_contract(rep, n):
    assert CONTRACT <= set(rep)
    for part in ("baseline", "final"):
        assert len(rep[part]["rms_fit"]) == n and len(rep[part]["rms_validate"]) == n
    for e in rep["effects"]:
        assert e["kind"] in EFFECTS
        assert e["joint"] is None or 0 <= e["joint"] < n
        assert isinstance(e["parameters"], dict) and len(e["rms_validate_after"]) == n
    assert isinstance(rep["unexplained_structure"], bool)
    assert set(rep["replay"]) == {"before", "after"}


@pytest.fixture(scope="module")
def c1_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("repair_c1")
    fit = sorted(glob.glob(os.path.join(C1, "20230629-143*.csv")))
    val = sorted(glob.glob(os.path.join(C1, "20230629-154*.csv")))
    status = cli.main(["repair", *fit, "--robot", "dfki_double_pendulum_c1", "--validate", *val,
                       "--out", str(out)])
    assert status == 0
    with open(out / "report.json") as fh:
        return json.load(fh), out


@needs_data
def test_c1_validation_error_drops_on_both_joints(c1_report):
    rep, out = c1_report
    _check_contract(rep, 2)
    assert rep["torque"] == "tau_meas" and rep["data"]["fit"]["filter"]["cutoff_hz"] == 8.0
    assert rep["effects"], "no effect added on C.1"
    before, after = rep["baseline"]["rms_validate"], rep["final"]["rms_validate"]
    # lower on both joints, by a margin (measured 2026-11-22: -21 % and -19 %)
    assert all(a < 0.95 * b for a, b in zip(after, before)), (before, after)
    assert rep["verdict"] == "repaired" and all(e["kept"] for e in rep["effects"])
    # never worse, against the least-squares baseline itself (IV + presliding beats it everywhere)
    tol = rep["never_worse"]["tolerance"]
    assert all(a <= b * (1 + tol) for a, b in zip(after, before))
    # the replayed motion (Drake plant, measured torques, resets from measured states) too
    rb, ra = rep["replay"]["before"]["rms_q"], rep["replay"]["after"]["rms_q"]
    assert all(a < 0.9 * b for a, b in zip(ra, rb)), (rb, ra)
    assert (out / "report.md").exists() and (out / "residual_fit.png").exists()


@needs_data
def test_c1_export_urdf_is_the_consistent_model_in_drake(c1_report, tmp_path):
    """Issue 23: the repaired C.1 model's URDF (to_urdf) loads in Drake; Drake's inverse dynamics
    of it equals the physically consistent model's rigid-body prediction on the validation
    states to 1e-9 N m, and to_urdf -> load_export -> predict_torque equals the model's
    prediction including its effects (presliding friction, in the sidecar)."""
    from pydrake.multibody.tree import MultibodyForces

    from robust_drake.identification.data import load
    from robust_drake.identification.model import IdentifiedModel
    from robust_drake.models import make_plant
    from robust_drake.regressor import InverseDynamicsRegressor

    rep, _ = c1_report
    model = IdentifiedModel.from_report(rep)
    out = model.to_urdf(tmp_path / "c1_identified.urdf")
    cm = model.consistent_model()
    val = load(sorted(glob.glob(os.path.join(C1, "20230629-154*.csv"))), robot=rep["robot"], n_joints=2, quiet=True)
    rigid = InverseDynamicsRegressor.from_robot(rep["robot"]).evaluate(val.q, val.qd, val.qdd) @ cm.base_values
    plant = make_plant(out["urdf"])
    ctx = plant.CreateDefaultContext()
    f = MultibodyForces(plant)  # zero: gravity added below, the URDF's damping left out
    err = 0.0
    for k in range(0, val.N, 5):
        plant.SetPositions(ctx, val.q[k])
        plant.SetVelocities(ctx, val.qd[k])
        tau = plant.CalcInverseDynamics(ctx, val.qdd[k], f) - plant.CalcGravityGeneralizedForces(ctx)
        err = max(err, float(np.abs(tau - rigid[k]).max()))
    assert err < 1e-9, err
    back = IdentifiedModel.from_export(out["urdf"])
    full = cm.predict_torque(val.q, val.qd, val.qdd)
    assert np.abs(back.predict_torque(val.q, val.qd, val.qdd) - full).max() < 1e-9
    assert [e.kind for e in back.effects] == [e.kind for e in cm.effects]  # presliding friction kept
    # the exported bodies are the repair's consistent fit (report.json "consistent"), to round-off
    for name, b in rep["consistent"]["bodies"].items():
        assert np.allclose(cm.consistent["bodies"][name]["inertia_origin"], b["inertia_origin"], rtol=0, atol=1e-8)
        assert cm.consistent["bodies"][name]["mass"] == pytest.approx(b["mass"], rel=1e-12)


@needs_data
def test_c1_regressor_noise_is_detected_and_removed(c1_report):
    """Errors in variables: the Hausman test rejects LS on C.1, and the IV estimate's gravity
    parameters move back towards the URDF's (the lab's own identification) and the swing-ups'."""
    rep, _ = c1_report
    est = rep["estimator"]
    assert est["method"] == "instrumental_variables"
    assert est["hausman"]["statistic"] > 5 * est["hausman"]["limit"]
    # and the output-error check on the fit data agrees: IV replays the open-loop runs better
    assert est["replay_fit"]["ratio"] < 0.95
    ls, iv = rep["baseline"]["parameters"], rep["final"]["parameters"]
    for name in ("mx_link1 + 0.2*m_link2", "mx_link2"):
        assert iv[name] > 1.05 * ls[name], (name, ls[name], iv[name])
    # the shift against the URDF shrinks with it
    assert rep["nominal"]["chi2"] < 0.7 * _ls_shift_chi2(rep)


def _ls_shift_chi2(rep):
    from robust_drake.identification.least_squares import load_regressor
    from robust_drake.model_repair.nominal import chi2, shift_weights

    reg = load_regressor(rep["robot"])
    th0 = reg.base_parameters()
    th = np.array([rep["baseline"]["parameters"][n] for n in reg.base_names])
    se = np.array([rep["baseline"]["standard_errors"][n] for n in reg.base_names])
    return chi2(th - th0, shift_weights(th0, se))


@needs_data
def test_c1_least_squares_parameters_shrink_as_the_cutoff_rises():
    """The signature of noisy regressors (attenuation): the LS gravity parameters of the C.1
    open-loop runs fall as the filter lets more differentiated encoder noise through, while the
    IV estimates (instruments at half the cut-off) move much less."""
    from robust_drake.identification.instruments import cutoff_sweep
    from robust_drake.identification.least_squares import load_regressor

    robot = "dfki_double_pendulum_c1"
    reg = load_regressor(robot)
    files = sorted(glob.glob(os.path.join(C1, "20230629-143*.csv")))
    k = list(reg.base_names).index("mx_link2")
    sweep = cutoff_sweep(files, robot, reg, [4.0, 8.0, 12.0], n_joints=2)
    ls = [row[k] for row in sweep["least_squares"]]
    iv = [row[k] for row in sweep["instrumental_variables"]]
    assert ls[0] > ls[1] > ls[2], ls
    assert (ls[0] - ls[2]) / ls[0] > 0.15, ls
    assert abs(iv[0] - iv[2]) < 0.5 * abs(ls[0] - ls[2]), (ls, iv)


@needs_data
def test_c1_effects_are_physically_plausible(c1_report):
    rep, _ = c1_report
    for e in rep["effects"]:
        p = e["parameters"]
        if e["kind"] == "time_delay":
            # CAN bus + driver current loop at a 500 Hz control rate: a few ms, never negative
            assert 0.0 < p["delay"] < 0.02
        elif e["kind"] == "load_dependent_friction":
            assert 0.0 < p["load_coefficient"] < 0.5
        elif e["kind"] == "rotor_inertia":
            # AK80-6: gr^2 Ir = 36 * 6.07e-5 = 2.2e-3 kg m^2; a factor 3 either way
            assert 7e-4 < p["reflected_inertia"] < 7e-3
        elif e["kind"] == "torque_scale":
            assert abs(p["gain_error"]) < 0.3
        elif e["kind"] == "presliding_friction":
            # Dahl build-up after reversals: positive, and with the Coulomb level a total friction
            # of the size a small planetary QDD joint has (the lab's files: cf1 0.16-0.17 N m)
            fc = rep["final"]["parameters"][f"fc{e['joint'] + 1}"]
            assert p["presliding_torque"] > 0.0 and 0.0 < fc and fc + p["presliding_torque"] < 0.5
        else:
            raise AssertionError(f"no plausibility rule for {e['kind']} on C.1: {e}")
    # the consistent estimate: every link's pseudo-inertia PSD, masses of a few hundred grams
    cons = rep["consistent"]
    assert min(cons["min_pseudo_inertia_eig"]) >= -1e-8
    for body in cons["bodies"].values():
        assert 0.05 < body["mass"] < 3.0


@needs_data
def test_same_command_runs_on_design_a0(tmp_path):
    out = tmp_path / "a0"
    files = sorted(glob.glob(os.path.join(A0, "*.csv")))
    status = cli.main(["repair", *files, "--robot", "dfki_double_pendulum_a0", "--out", str(out)])
    assert status == 0
    rep = json.load(open(out / "report.json"))
    _check_contract(rep, 2)
    # no --validate: a 25 % contiguous tail of every file is held out, and the report says so
    assert rep["data"]["validation_source"] == "tail of fit files"
    assert rep["samples_validate"] == pytest.approx(rep["samples"] / 3, rel=0.02)
    assert any("held out" in n for n in rep["notes"])
    assert rep["robot"] == "dfki_double_pendulum_a0"
    # the baseline fits A.0 far better than a zero model: the residual is a fraction of the torque
    tau_max = rep["data"]["fit"]["tau_max"]
    assert all(r < 0.3 * t for r, t in zip(rep["baseline"]["rms_fit"], tau_max))
    # A.0's encoder noise biases LS too (Hausman significant), but on the held-out tail of the
    # same runs the IV model's torque error is higher than LS's on both joints (measured +10 % /
    # +5 %: with equally noisy columns there, the shrunken LS parameters are the better
    # equation-error predictor). The IV switch is held to the same per-joint never-worse rule as
    # an effect (issue 13): it is tried, dropped, and the report says so.
    assert rep["estimator"]["hausman"]["significant"]
    iv_val, ls_val = rep["estimator"]["baseline_iv"]["rms_validate"], rep["baseline"]["rms_validate"]
    assert all(i > 1.02 * b for i, b in zip(iv_val, ls_val)), (iv_val, ls_val)
    assert rep["estimator"]["method"] == "least_squares"
    assert [d["kind"] for d in rep["rejected_effects"]].count("estimator") == 1
    # never worse against the least-squares baseline on every joint
    tol = rep["never_worse"]["tolerance"]
    ref = rep["never_worse"]["reference_rms_validate"]
    assert ref == pytest.approx(rep["baseline"]["rms_validate"])
    assert all(a <= b * (1 + tol) for a, b in zip(rep["final"]["rms_validate"], ref))


@needs_data
@pytest.mark.parametrize("x0", [0.003, 0.01, 0.03])
def test_c1_joint0_friction_lags_at_reversals_presliding_friction(x0):
    """With the command's defaults (tau_meas, 8 Hz) the joint-0 residual of C.1 dips at every
    velocity reversal. A Dahl presliding friction on joint 0 (friction builds up over x0 rad
    after a reversal), fitted on the open-loop runs only, must predict the swing-ups' joint-0
    torque clearly better for every x0 of the library's grid (not one tuned value), with a
    positive build-up torque and a total friction level (fc1 + F_d) of the size a small
    planetary QDD joint has (< 0.5 N m). Joint 1 is not improved by it (nor by any library
    effect, see BUILD_NOTES "Identification and repair")."""
    from robust_drake.identification.data import load
    from robust_drake.effects import make_effect
    from robust_drake.identification.least_squares import load_regressor, solve_wls
    from robust_drake.model_repair.selection import ColumnCache, fit_model, predict_tau

    robot = "dfki_double_pendulum_c1"
    reg = load_regressor(robot)
    fit = load(sorted(glob.glob(os.path.join(C1, "20230629-143*.csv"))), robot=robot, n_joints=2)
    val = load(sorted(glob.glob(os.path.join(C1, "20230629-154*.csv"))), robot=robot, n_joints=2)
    assert fit.filter.cutoff_hz == 8.0  # the defaults
    cf, cv = ColumnCache(fit, reg), ColumnCache(val, reg)
    Y0, names0, _ = cf.model([])
    w = 1.0 / solve_wls(Y0, fit.tau, names0, warn=False).rms
    base, _ = fit_model(cf, [], w)
    eff = make_effect("presliding_friction", 0, presliding_displacement=x0)
    rep, sl = fit_model(cf, [eff], w)
    rms = lambda r: np.sqrt(np.mean(r ** 2, axis=0))  # noqa: E731
    before = rms(val.tau - predict_tau(cv, [], base.theta))
    after = rms(val.tau - predict_tau(cv, [eff], rep.theta))
    Fd = eff.parameters(rep.theta[sl[0]])["presliding_torque"]
    fc1 = dict(zip(rep.names, rep.theta))["fc1"]
    assert Fd > 0.05 and 0.0 < fc1 and fc1 + Fd < 0.5, (Fd, fc1)
    assert after[0] < 0.9 * before[0], (before, after)


def test_cli_rejects_bad_input_with_a_message(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,q1,tau1\n0,0,0\n")
    status = cli.main(["repair", str(bad), "--robot", "dfki_double_pendulum_c1", "--out", str(tmp_path / "o")])
    assert status == 2
    assert "error:" in capsys.readouterr().err


def test_demo_finds_the_hidden_effect_and_replay_improves(tmp_path):
    from robust_drake.synthetic.simulated import run_repair_demo

    rep = run_repair_demo(str(tmp_path), progress=None)
    truth = rep["truth"]
    first = rep["effects"][0]
    assert (first["kind"], first["joint"]) == (truth["kind"], truth["joint"])
    assert first["parameters"]["stribeck_torque"] == pytest.approx(truth["parameters"]["stribeck_torque"], rel=0.3)
    j = truth["joint"]
    assert rep["final"]["rms_validate"][j] <= 0.5 * rep["baseline"]["rms_validate"][j]
    # the repaired Drake plant (with the stribeck block) follows the measured motion better
    assert max(rep["replay"]["after"]["rms_q"]) < 0.5 * max(rep["replay"]["before"]["rms_q"])
    assert os.path.exists(tmp_path / "report.md")
    # the report's effects become plant-side blocks for a closed-loop diagram; the Stribeck block
    # opposes motion on its joint and is largest at low speed
    from robust_drake.identification.model import IdentifiedModel
    from robust_drake.model_repair.pipeline import effects_from_report

    hooks = IdentifiedModel.from_report(rep).closed_loop_hooks(plant=True, controller=False, rigid_body=False)
    blocks = [f(type("Ctx", (), {"n": 2})()) for f in hooks["effects"]]
    assert hooks["plant_setup"] == []
    assert len(blocks) == 1 and blocks[0].HasInputPort("state")
    eff, params = effects_from_report(rep)[0]
    coef = eff.coef_from_parameters(params, 2)
    slow = eff.generalized_force(np.zeros(2), np.array([0.0, 0.1]), None, coef)[j]
    fast = eff.generalized_force(np.zeros(2), np.array([0.0, 2.0]), None, coef)[j]
    assert slow < 0 and abs(fast) < 0.1 * abs(slow)


@needs_data
def test_a_joint_worse_inside_the_margin_is_named_in_the_verdict(tmp_path):
    """Data the tests did not generate otherwise: A.0 with fit and validation swapped, the fit log's
    stamps jittered by +-0.3 ms and 0.5 s cut out. The IV switch is kept (joint 2 -8 %), joint 1
    validates +4.4 % [+0.9, +7.8] worse: inside the 1 % never-worse margin, so "repaired" stands,
    but the verdict must say it (report.json and report.md alike), not read as an unqualified gain."""
    import pandas as pd

    df = pd.read_csv(os.path.join(A0, "20220815-trajectory_01.csv"))
    rng = np.random.default_rng(3)
    df["time"] = df["time"] + rng.uniform(-3e-4, 3e-4, len(df))
    fit = tmp_path / "fit.csv"
    df.drop(index=range(2000, 2250)).to_csv(fit, index=False)
    out = tmp_path / "rep"
    assert cli.main(["repair", str(fit), "--robot", "dfki_double_pendulum_a0", "--validate",
                     os.path.join(A0, "20220815-trajectory_00.csv"), "--out", str(out), "--no-plots"]) == 0
    rep = json.loads((out / "report.json").read_text())
    up = [j for j, t in enumerate(rep["final"]["validate_change"]) if t["low"] > 0]
    assert up, "the case no longer has a joint worse at the level (the test is about that joint)"
    md = (out / "report.md").read_text()
    for j in up:
        name = f"joint {j + 1} ({rep['joint_names'][j]}) validates +"
        assert name in rep["verdict_reason"] and name in md
