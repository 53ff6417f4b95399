"""The identified model as the product (issue 22): one typed path from logs to a controller.

* ``IdentifiedModel.predict`` gives exactly what the repair report scores (same filter, same
  columns, time-dependent effects, stuck rows left out as the fit leaves them out);
* ``rd.identify`` / ``rd.repair`` take files, arrays and DataFrames; ``rd.repair`` returns a
  read-only mapping over the report with the models;
* every effect kind of the library goes through ``IdentifiedModel`` into a closed loop, as the
  plant and as the controller's compensation, stateful and plant-modifying ones included;
* SP1 / SP2 / CI / BR take ``model=`` (theta0 and the set from the model);
* the Panda runs at the same rate and saturates at the same limits through ``simulate`` and
  ``run_batch``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import robust_drake as rd
from robust_drake.diagram import ClosedLoopConfig, build_closed_loop
from robust_drake.errors import RobustDrakeError
from robust_drake.effects import EFFECTS, make_effect
from robust_drake.identification.model import IdentifiedEffect, IdentifiedModel

C1 = "dfki_double_pendulum_c1"


@pytest.fixture(scope="module")
def periodic(tmp_path_factory):
    """A.0 arm with a 3.1 Hz torque disturbance on joint 1 (outside the library: the repair adds
    a periodic_disturbance, a time-dependent effect), 8 s logs; repaired without replay."""
    from robust_drake.synthetic.simulated_cases import outside_case

    out = tmp_path_factory.mktemp("periodic")
    fit, val, truth = outside_case("periodic_fast", out_dir=str(out), duration=8.0)
    res = rd.repair(fit, truth["robot"], validate=val, plots=False, replay=False, consistent=False, nominal=False,
                    progress=lambda m: None)
    return res, fit, val, truth


def test_predict_is_what_the_report_scores(periodic):
    """predict() on the validation log equals the report's rms_validate, on the fit log (stuck
    rows left out as the fit does) its rms_fit, for the baseline and the repaired model, to
    rounding; the unfiltered predict_torque needs the time stamps for the time-dependent effect."""
    res, fit, val, truth = periodic
    assert "periodic_disturbance" in [e.kind for e in res.model.effects]
    for model, key in ((res.model, "final"), (res.baseline_model, "baseline")):
        assert model.predict(val).rms == pytest.approx(res[key]["rms_validate"], rel=1e-12, abs=0)
        assert model.predict(fit, exclude_stuck=True).rms == pytest.approx(res[key]["rms_fit"], rel=1e-12, abs=0)
    with pytest.raises(RobustDrakeError, match="depends on time"):
        res.model.predict_torque(*_states(res.model, val))


def _states(model, path):
    from robust_drake.identification.data import load

    d = load([path], robot=model.robot, n_joints=model.n, quiet=True)
    return d.q, d.qd, d.qdd


def test_logs_as_arrays_and_dataframes_give_the_same_model(periodic):
    """identify() on a CSV file, on its columns as an array (t, q1..qn, tau1..taun) and as a
    DataFrame gives the same parameters; a wrong type is a one-line error."""
    import pandas as pd

    _, fit, val, truth = periodic
    df = pd.read_csv(fit)
    arr = df[["t", "q1", "q2", "tau1", "tau2"]].to_numpy()
    models = [rd.identify(x, truth["robot"], validate=val, progress=lambda m: None) for x in (fit, arr, df)]
    for m in models[1:]:
        np.testing.assert_allclose(m.base_values, models[0].base_values, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(m.coulomb, models[0].coulomb, rtol=1e-12, atol=1e-15)
    assert models[0].predict(arr).rms == pytest.approx(models[0].predict(fit).rms, rel=1e-12)
    for bad in ({"t": 1}, 3.0, np.zeros((100, 4))):
        with pytest.raises(RobustDrakeError) as err:
            rd.identify(bad, truth["robot"])
        assert "\n" not in str(err.value) and "identify" in str(err.value)


def test_repair_result_is_the_report_and_carries_the_models(periodic, tmp_path):
    res = periodic[0]
    assert isinstance(res, rd.RepairResult) and res["verdict"] == res.report["verdict"]
    assert dict(res) == res.report and json.loads(json.dumps(res.report)) == json.loads(json.dumps(dict(res)))
    with pytest.raises(TypeError):
        res["verdict"] = "x"  # read only
    np.testing.assert_array_equal(res.model.base_values, IdentifiedModel.from_report(res.report).base_values)
    assert res.to_markdown().startswith("#") and res["verdict"] in res.to_markdown()
    assert res.plot().axes
    path = res.model.save(tmp_path / "model.json")
    back = rd.IdentifiedModel.load(path)
    assert back.to_json() == json.loads(json.dumps(res.model.to_json()))
    with pytest.raises(RobustDrakeError, match="format"):
        res.model.save(tmp_path / "model.xyz")


# ------------------------------------------------------------------------------------ closed loop
def _c1_model(effect=None, coulomb=(0.05, 0.04), viscous=(0.01, 0.005)):
    """The C.1 URDF's rigid body as an identified model (covariance 1e-4 of each parameter's
    scale), with friction and at most one effect."""
    from robust_drake.regressor import InverseDynamicsRegressor

    reg = InverseDynamicsRegressor.from_robot(C1)
    th = reg.base_parameters()
    cov = np.diag((1e-2 * np.maximum(np.abs(th), 1e-3)) ** 2)
    return IdentifiedModel(robot=C1, joint_names=["j0", "j1"], base_names=list(reg.base_names), base_values=th,
                           base_covariance=cov, coulomb=np.array(coulomb), viscous=np.array(viscous),
                           effects=[] if effect is None else [effect], estimator="instrumental_variables",
                           data={"samples": 5000, "joints": 2, "dt": 0.004, "filter": {"cutoff_hz": 8.0},
                                 "covariance": {"kind": "sandwich", "parameters": len(th) + 4}})


SHAPES = {"periodic_disturbance": {"frequency": 2.0}, "dead_zone": {"threshold": 0.05}}


def _effect(kind):
    """One effect of ``kind`` on joint 1 (shared kinds on all joints), coefficients 0.02 (a delay:
    2 ms)."""
    cls = EFFECTS[kind]
    joint = None if cls.shared else 1
    shape = {k: v for k, v in SHAPES.get(kind, {}).items()}
    if "robot" in cls.default_shape:
        shape["robot"] = C1
    eff = make_effect(kind, joint, **shape)
    coef = np.full(eff.num_coef(2), 0.002 if kind == "time_delay" else 0.02)  # a 20 ms delay destabilises SP1
    params = {k: v for k, v in eff.parameters(coef).items() if k != "robot"}
    return IdentifiedEffect(kind, joint, params, coef.tolist())


def _run(plant_model, model, **kw):
    loop = build_closed_loop(ClosedLoopConfig(robot=C1, controller="sp1", trajectory="sine", rate=1000.0,
                                              duration=0.25, observer="exact", encoder_resolution=None,
                                              plant_model=plant_model, model=model, **kw))
    return loop, loop.simulate()


@pytest.mark.parametrize("kind", sorted(EFFECTS))
def test_every_effect_kind_goes_into_a_closed_loop_as_plant_and_as_compensation(kind):
    """As the plant: a force-type effect (stateful, torque- and time-dependent, the delay line
    included) is a block of the loop and changes the motion; a plant-modifying one changes M(q)
    by its own term (rotor inertia: I_r on the diagonal; payload: its point mass's M). As the
    controller's model (SP1 with model=): fed forward, compensated by its block (stateful), or
    named with the reason it is not; where compensated the command differs from SP1 without it."""
    ie = _effect(kind)
    with_e, without = _c1_model(ie), _c1_model()
    loop, res = _run(with_e, with_e)
    ref_loop, ref = _run(with_e, without)  # same arm, the controller does not know the effect
    bare_loop, bare = _run(without, without)
    assert not (res.diverged or ref.diverged or bare.diverged), (res.divergence_reason, ref.divergence_reason)
    eff = ie.effect(C1)
    if eff.modifies_plant:
        q = np.array([0.3, -0.7])
        dM = _mass(loop, res, q) - _mass(bare_loop, bare, q)
        if kind == "rotor_inertia":
            np.testing.assert_allclose(dM, np.diag([0.0, 0.02]), atol=1e-12)
        else:  # payload: M of a point mass m at the tool = its columns' qdd part
            cols = np.stack([eff.evaluate_columns(q[None], np.zeros((1, 2)), np.eye(2)[j][None])[0, :, 0]
                             - eff.evaluate_columns(q[None], np.zeros((1, 2)), np.zeros((1, 2)))[0, :, 0]
                             for j in range(2)], axis=1)
            np.testing.assert_allclose(dM, 0.02 * cols, atol=1e-10)
    else:
        assert any(kind in b.get_name() for b in loop.effect_blocks), [b.get_name() for b in loop.effect_blocks]
        assert np.abs(ref.q - bare.q).max() > 1e-9  # the effect acts on the arm
    ctrl = loop.controller
    blocks = [b.get_name() for b in loop.compensation_blocks]
    fed = kind in [t.split("[")[0] for t in with_e.closed_loop_hooks(controller=True)["feedforward"][0].terms]
    if fed or blocks:
        assert np.abs(np.asarray(res.u) - np.asarray(ref.u)).max() > 1e-9
    else:
        assert kind in ctrl.not_compensated and len(ctrl.not_compensated[kind]) > 20


def _mass(loop, res, q):
    plant = loop.plant
    ctx = plant.GetMyContextFromRoot(res.context)
    plant.SetPositions(ctx, q)
    return plant.CalcMassMatrix(ctx)


def test_feedforward_no_longer_dies_on_a_stateful_effect_and_plant_changes_are_not_dropped():
    """Through the model's one door: a stateful effect is left out of the feedforward and handed
    to the controller as a compensation block; a plant-modifying one (rotor inertia) has no block
    but a plant setup that adds its I_r = 0.02 kg m^2 to M(q)."""
    from robust_drake.effects import load_plant

    hooks = _c1_model(_effect("presliding_friction")).closed_loop_hooks(controller=True)
    (ff,) = hooks["feedforward"]
    assert "presliding_friction" in ff.skipped and ff.reasons["presliding_friction"] == "block"
    assert np.all(np.isfinite(ff(np.zeros(2), np.ones(2))))
    assert len(hooks["compensation"]) == 1 and "presliding_friction" not in hooks["not_compensated"]
    plant_side = _c1_model(_effect("rotor_inertia")).closed_loop_hooks(plant=True, controller=False, rigid_body=False)
    assert plant_side["effects"] == [] and len(plant_side["plant_setup"]) == 1
    plant = load_plant(C1)
    ctx, bare = plant.CreateDefaultContext(), plant.CreateDefaultContext()
    q = np.array([0.3, -0.7])
    plant_side["plant_setup"][0](plant, ctx)
    for c in (ctx, bare):
        plant.SetPositions(c, q)
    np.testing.assert_allclose(plant.CalcMassMatrix(ctx) - plant.CalcMassMatrix(bare), np.diag([0.0, 0.02]), atol=1e-12)


def test_controllers_take_theta0_and_the_set_from_the_model():
    """SP1: rho = sqrt(lambda_max(P)), SP2: rho_i = sqrt(P_ii), CI: E E^T = P, all with theta0 =
    the model's base parameters (P = the model's 99 % confidence set); a model of another arm is
    refused."""
    m = _c1_model()
    ell = m.confidence_set(0.01)
    for name, check in (("sp1", lambda c: np.isclose(c.rho, np.sqrt(np.linalg.eigvalsh(ell.P)[-1]))),
                        ("sp2", lambda c: np.allclose(c.rho, np.sqrt(np.diag(ell.P)))),
                        ("calafiore", lambda c: np.allclose(c.E @ c.E.T, ell.P, rtol=1e-9, atol=1e-15))):
        loop = build_closed_loop(ClosedLoopConfig(robot=C1, controller=name, trajectory="sine", rate=1000.0,
                                                  duration=0.2, model=m))
        c = loop.controller
        np.testing.assert_allclose(c.theta0, m.base_values)
        assert check(c), name
        assert c.uncertainty["kind"] == "ellipsoid" and c.uncertainty["theta0"] == ell.theta0.tolist()
    with pytest.raises(RobustDrakeError, match="base parameters"):
        build_closed_loop(ClosedLoopConfig(robot="siciliano_2link", controller="sp1", trajectory="sine",
                                           duration=0.2, model=m))


def test_bascetta_case_b_with_an_identified_model_tracks_its_arm():
    """BR Case B with model=: M_hat, n_hat of the identified rigid body, bounds over its set; on
    the identified arm it tracks at least as well as Case B with the default perturbed model."""
    m = _c1_model()
    runs = {}
    for label, model in (("urdf", None), ("model", m)):
        runs[label] = rd.simulate(ClosedLoopConfig(robot=C1, controller="bascetta_b", trajectory="step",
                                                   duration=1.0, plant_model=m, model=model))
        assert not runs[label].diverged
    assert runs["model"].metrics["maxerr2"] <= runs["urdf"].metrics["maxerr2"]


def test_closed_loop_config_yaml_round_trip(tmp_path):
    """to_yaml / from_yaml: the resolved config with the identified model embedded runs the same
    loop, to the last bit."""
    m = _c1_model(_effect("position_dependent"))
    cfg = ClosedLoopConfig(robot=C1, controller="sp1", trajectory="sine", rate=1000.0, duration=0.2, model=m,
                           plant_model=m)
    path = tmp_path / "loop.yaml"
    cfg.to_yaml(path)
    back = ClosedLoopConfig.from_yaml(path)
    a, b = rd.simulate(cfg), rd.simulate(back)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.u, b.u)
    with pytest.raises(RobustDrakeError, match="unknown closed-loop field"):
        ClosedLoopConfig.from_dict({"robto": "d2r2"})


def test_panda_same_rate_and_torque_limits_through_simulate_and_run_batch():
    """The Panda's 1 kHz and its 87/12 N m limits come from its description on both paths; the
    SP1 command beyond them is clipped there (joint 0 asks ~180 N m on the sine)."""
    from robust_drake.description import describe
    from robust_drake.scenario import Scenario

    lim = list(describe("panda").torque_limits)
    direct = ClosedLoopConfig(robot="panda", controller="sp1", trajectory="sine", duration=0.6)
    batch = Scenario(robot="panda", controller="sp1", trajectory="sine", duration=0.6)
    for c in (direct.resolved(), batch.to_config().resolved()):
        assert c.rate == 1000.0 and c.torque_limit == lim
    res = rd.simulate(direct)
    df = rd.run_batch([batch], workers=1, progress=False)
    assert df["rate"].iloc[0] == 1000.0
    assert df["maxerr1"].iloc[0] == res.metrics["maxerr1"]
    assert np.abs(res.u[:, 0]).max() > 1.5 * lim[0]
    assert np.all(np.abs(res.tau) <= np.asarray(lim) + 1e-12) and np.abs(res.tau[:, 0]).max() == lim[0]
    assert df["tau_peak1"].iloc[0] == lim[0]


def test_batch_scenarios_are_overrides_of_the_closed_loop_config(tmp_path):
    """A batch spec may set any ClosedLoopConfig field at the top level or per scenario (here the
    torque limit and the metrics window); what it leaves out is ClosedLoopConfig's default (the
    robot description's rate)."""
    from robust_drake.scenario import Scenario, load_spec

    spec = tmp_path / "spec.yaml"
    spec.write_text("robot: panda\ncontroller: pd\ntrajectory: sine\nduration: 0.1\ntorque_limit: [50, 50, 50, 50, 10, 10, 10]\n"
                    "scenarios:\n  - {metrics_skip: 0.05}\n  - {load: none}\n")
    scenarios, _ = load_spec(spec)
    configs = [s.to_config().resolved() for s in scenarios]
    assert [c.torque_limit for c in configs] == [[50, 50, 50, 50, 10, 10, 10]] * 2
    assert [c.metrics_skip for c in configs] == [0.05, 0.0] and all(c.rate == 1000.0 for c in configs)
    assert Scenario.from_dict({"robot": "panda", "encoder_resolution": 1e-6}).extra == {"encoder_resolution": 1e-6}
    with pytest.raises(RobustDrakeError, match="both"):
        Scenario.from_dict({"torque_limit": [1.0, 1.0], "extra": {"torque_limit": [2.0, 2.0]}})
