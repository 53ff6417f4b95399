"""IdentifiedModel: the one object passed from identification (repair) to control.

A simulated arm (the default 2-DOF URDF) with a hidden 4-per-rev cogging torque on joint 1 is
repaired; the model in the report must survive a JSON round trip with the same torques, predict
the validation torques it was judged on, and give a controller a feedforward that cancels the
real cogging torque of the simulated arm.
"""

import json

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.identification.model import IdentifiedModel


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair
    from robust_drake.synthetic.simulated import hidden_effect_case

    out = tmp_path_factory.mktemp("model")
    fit, val, truth = hidden_effect_case("position_dependent", seed=0, out_dir=str(out), duration=10.0)
    rep = run_repair([fit], RepairOptions(robot=truth["robot"], plots=False, replay=False, consistent=False),
                     validate_paths=[val])
    return rep, truth, val


def _feedforward(model):
    """The controller's feedforward term f(q, v) of the model's one door to a loop."""
    (ff,) = model.closed_loop_hooks(controller=True)["feedforward"]
    return ff


def _states(n, rng, count=50):
    return (rng.uniform(-np.pi, np.pi, (count, n)), rng.uniform(-2, 2, (count, n)), rng.uniform(-5, 5, (count, n)))


def test_json_round_trip_gives_the_same_torques(case):
    rep, truth, _ = case
    model = IdentifiedModel.from_report(rep)
    assert [e.kind for e in model.effects] == ["position_dependent"]
    back = IdentifiedModel.from_json(json.loads(json.dumps(model.to_json())))
    q, qd, qdd = _states(model.n, np.random.default_rng(3))
    np.testing.assert_allclose(back.predict_torque(q, qd, qdd), model.predict_torque(q, qd, qdd), rtol=0, atol=1e-12)
    ff, ff_back = _feedforward(model), _feedforward(back)
    np.testing.assert_allclose(ff_back(q[0], qd[0]), ff(q[0], qd[0]), rtol=0, atol=1e-12)
    assert back.joint_names == model.joint_names and len(set(model.joint_names)) == model.n


def test_model_predicts_the_validation_torque(case):
    """The model evaluated on the validation data's (filtered) states reproduces the measured
    torque about as well as the report says, and better than the baseline model on joint 1."""
    from robust_drake.identification.data import load

    rep, truth, val = case
    data = load([val], robot=truth["robot"], n_joints=2)
    err = {}
    for stage in ("baseline", "final"):
        m = IdentifiedModel.from_report(rep, stage)
        r = data.tau - m.predict_torque(data.q, data.qd, data.qdd)
        err[stage] = np.sqrt(np.mean(r**2, axis=0))
    j = truth["joint"]
    assert err["final"][j] < 0.6 * err["baseline"][j], err
    # the repair filters the columns in parallel with the torque (not done here; measured 0.0030
    # here vs 0.0021 N m reported): the same size within a factor 1.5
    assert err["final"][j] < 1.5 * rep["final"]["rms_validate"][j], (err, rep["final"]["rms_validate"])


def test_feedforward_cancels_the_true_cogging(case):
    """Feedforward minus the friction part = the torque the motors must add against the arm's
    real cogging, i.e. minus the true block's generalized force (amplitude 0.06 N m)."""
    from robust_drake.effects import make_effect

    rep, truth, _ = case
    model = IdentifiedModel.from_report(rep)
    ff = _feedforward(model)
    p = truth["parameters"]
    true = make_effect("position_dependent", truth["joint"], harmonic=p["harmonic"])
    coef = true.coef_from_parameters(p, 2)
    v = np.array([0.7, -0.4])
    errs = []
    for q1 in np.linspace(-np.pi, np.pi, 41):
        q = np.array([0.2, q1])
        cogging = ff(q, v) - (model.coulomb * np.sign(v) + model.viscous * v)
        errs.append(cogging + true.generalized_force(q, v, None, coef))
    errs = np.abs(np.array(errs))
    assert errs[:, 0].max() < 1e-12  # nothing on joint 0
    assert errs[:, 1].max() < 0.3 * p["amplitude"], errs[:, 1].max()


def test_repair_control_takes_the_model_not_the_report_keys(case):
    """experiments/repair_control builds its feedforward from the IdentifiedModel alone: a report
    whose parsed-by-name parts are removed gives the same torques; one without a model is refused."""
    from robust_drake.experiments.repair_control import model_feedforward

    rep, _, _ = case
    slim = {k: rep[k] for k in ("model", "baseline_model")}
    q, v = np.array([0.3, -1.1]), np.array([0.5, -0.2])
    for stage in ("baseline", "final"):
        np.testing.assert_allclose(model_feedforward(slim, stage)(q, v), model_feedforward(rep, stage)(q, v))
    assert model_feedforward(rep, "final").terms and not model_feedforward(rep, "baseline").terms
    with pytest.raises(RobustDrakeError, match="model"):
        model_feedforward({"final": rep["final"], "effects": rep["effects"]}, "final")


def test_effect_blocks_apply_the_model_force(case):
    """The block the model's door puts on the plant side of a loop outputs the effect's
    generalized force for the model's coefficients (the same law the feedforward cancels)."""
    rep, truth, _ = case
    model = IdentifiedModel.from_report(rep)
    hooks = model.closed_loop_hooks(plant=True, controller=False, rigid_body=False)
    assert hooks["plant_setup"] == []  # a force-type effect: a block, no plant change
    (factory,) = hooks["effects"]
    blk = factory(type("Ctx", (), {"n": 2})())
    x = np.array([0.2, 0.9, 0.5, -0.3])
    ctx = blk.CreateDefaultContext()
    blk.GetInputPort("state").FixValue(ctx, x)
    eff = model.effects[0]
    expected = eff.effect().generalized_force(x[:2], x[2:], None, np.asarray(eff.coefficients))
    np.testing.assert_allclose(blk.GetOutputPort("generalized_force").Eval(ctx), expected, atol=1e-12)
    assert abs(expected[1]) > 0.01 and expected[0] == 0.0
    assert blk.HasInputPort("state")
