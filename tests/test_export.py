"""Issue 23: ``IdentifiedModel.to_urdf`` / ``identification.export`` and ``repair --export-urdf``.

Checked against Drake: the exported URDF is parsed by Drake's own parser and its
MultibodyPlant inverse dynamics is compared with the model's regressor prediction; the round
trip (to_urdf -> load_export -> predict_torque) with the model's prediction including effects.
The DFKI C.1 repair's export is in ``test_repair_dfki.py`` (it reuses that module's repair).
"""

import json
import os

import numpy as np
import pytest

from robust_drake import cli
from robust_drake.errors import RobustDrakeError
from robust_drake.identification.model import IdentifiedModel


def _model_from_urdf(robot, viscous=(0.02, -0.01), coulomb=(0.1, 0.05), effects=()):
    """An IdentifiedModel whose consistent fit is the URDF's own arm (every link, rotor inertias)."""

    from robust_drake.regressor import InverseDynamicsRegressor

    reg = InverseDynamicsRegressor.from_robot(robot)
    pi = reg.standard_parameters()
    names = list(reg.standard_names)
    nb = sum(1 for x in names if x.startswith("m_"))
    bodies = {}
    for i in range(nb):
        p = pi[10 * i:10 * i + 10]
        bodies[names[10 * i][2:]] = {"mass": float(p[0]), "com": (p[1:4] / p[0]).tolist(),
                                     "inertia_origin": p[4:10].tolist()}
    extras = {nm: float(v) for nm, v in zip(names[10 * nb:], pi[10 * nb:])}
    theta = reg.base_from_standard(pi)
    effs = [e for e, _ in effects]
    cons = {"solver": "test", "bodies": bodies, "extras": extras, "base_values": theta.tolist(),
            "coulomb": list(coulomb), "viscous": list(viscous), "effect_coefficients": [c for _, c in effects],
            "min_pseudo_inertia_eig": [0.0] * nb}
    return IdentifiedModel(robot=robot, joint_names=["joint1", "joint2"], base_names=list(reg.base_names),
                           base_values=theta, base_covariance=None, coulomb=np.asarray(coulomb),
                           viscous=np.asarray(viscous), effects=effs, consistent=cons)


def _states(n=40, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-3, 3, (n, 2)), rng.uniform(-2, 2, (n, 2)), rng.uniform(-10, 10, (n, 2))


def test_export_of_a_known_arm_is_that_arm_in_drake_and_round_trips(tmp_path):
    from pydrake.multibody.tree import MultibodyForces

    from robust_drake.identification.model import IdentifiedEffect
    from robust_drake.models import make_plant

    cog = IdentifiedEffect("position_dependent", 1, {"harmonic": 4, "amplitude": 0.05, "phase": 0.3},
                           [0.05 * np.cos(0.3), 0.05 * np.sin(0.3)])
    rot = IdentifiedEffect("rotor_inertia", 1, {"reflected_inertia": 0.004}, [0.004])
    m = _model_from_urdf("dfki_double_pendulum_c1", effects=[(cog, cog.coefficients), (rot, rot.coefficients)])
    out = m.to_urdf(tmp_path / "arm.urdf")
    assert os.path.isfile(out["urdf"]) and os.path.isfile(out["sidecar"])
    assert out["effects_in_sidecar"] == ["position_dependent"]  # the rotor inertia went into the URDF
    assert any("viscous" in n for n in out["notes"])  # the negative level could not be a damping
    q, qd, qdd = _states()
    cm = m.consistent_model()
    # Drake's own plant of the exported file against the model (rigid body + rotor + damping)
    plant = make_plant(str(tmp_path / "arm.urdf"))
    ctx = plant.CreateDefaultContext()
    f = MultibodyForces(plant)
    tau_d = []
    for k in range(len(q)):
        plant.SetPositions(ctx, q[k])
        plant.SetVelocities(ctx, qd[k])
        plant.CalcForceElementsContribution(ctx, f)  # gravity and the URDF's joint damping
        tau_d.append(plant.CalcInverseDynamics(ctx, qdd[k], f))
    from robust_drake.regressor import InverseDynamicsRegressor

    reg = InverseDynamicsRegressor.from_robot("dfki_double_pendulum_c1")
    expect = reg.evaluate(q, qd, qdd) @ cm.base_values + np.maximum(cm.viscous, 0) * qd + 0.004 * qdd * [0, 1]
    assert np.abs(np.asarray(tau_d) - expect).max() < 1e-9
    back = IdentifiedModel.from_export(out["urdf"])
    assert np.abs(back.predict_torque(q, qd, qdd) - cm.predict_torque(q, qd, qdd)).max() < 1e-9
    assert IdentifiedModel.from_export(out["sidecar"]).robot == back.robot
    # the generic loader takes the export too (URDF or sidecar), as `simulate --model` does
    for path in (out["urdf"], out["sidecar"]):
        loaded = IdentifiedModel.load(path)
        assert np.abs(loaded.predict_torque(q, qd, qdd) - back.predict_torque(q, qd, qdd)).max() < 1e-12


def test_export_refuses_models_without_a_consistent_body(tmp_path):
    m = _model_from_urdf("dfki_double_pendulum_c1")
    bare = type(m)(**{**m.__dict__, "consistent": None})
    with pytest.raises(RobustDrakeError, match="no physically consistent fit"):
        bare.to_urdf(tmp_path / "a.urdf")
    bad = json.loads(json.dumps(m.consistent))
    body = bad["bodies"]["link1"]
    body["inertia_origin"][0] = -0.05  # Ixx about the origin < 0: no rigid body
    with pytest.raises(RobustDrakeError, match="no physically consistent body for link 'link1'"):
        type(m)(**{**m.__dict__, "consistent": bad}).to_urdf(tmp_path / "b.urdf")
    with pytest.raises(RobustDrakeError, match="ending in .urdf"):
        m.to_urdf(tmp_path / "c.xml")
    assert not list(tmp_path.iterdir())


def test_identified_model_json_carries_the_consistent_fit_and_stays_backward_compatible():


    m = _model_from_urdf("dfki_double_pendulum_c1")
    d = m.to_json()
    assert IdentifiedModel.from_json(json.loads(json.dumps(d))).consistent == m.consistent
    old = {k: v for k, v in d.items() if k != "consistent"}
    assert IdentifiedModel.from_json(old).consistent is None


@pytest.mark.slow
def test_repair_export_urdf_on_the_command_line(tmp_path, capsys):
    from robust_drake.synthetic.simulated import hidden_effect_case

    fit, val, truth = hidden_effect_case("position_dependent", seed=0, out_dir=str(tmp_path / "data"), duration=8.0)
    urdf = tmp_path / "exp" / "c1_identified.urdf"
    args = ["repair", fit, "--robot", truth["robot"], "--validate", val, "--out", str(tmp_path / "rep"),
            "--no-plots", "--no-replay", "--export-urdf", str(urdf)]
    assert cli.main(args + ["--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["export"]["urdf"] == str(urdf) and urdf.is_file()
    model = IdentifiedModel.from_export(urdf)
    assert [e.kind for e in model.effects] == [e["kind"] for e in rep["model"]["effects"]
                                               if e["kind"] != "rotor_inertia"]
    # the export reproduces the repair's physically consistent prediction on the validation log
    from robust_drake.identification.data import load


    data = load(val, robot=truth["robot"], quiet=True)
    cm = IdentifiedModel.from_report(rep).consistent_model()
    assert np.abs(model.predict_torque(data.q, data.qd, data.qdd)
                  - cm.predict_torque(data.q, data.qd, data.qdd)).max() < 1e-9
    # an existing export is not overwritten without --force; --no-consistent cannot export
    assert cli.main(args) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert cli.main(args[:-2] + ["--no-consistent", "--export-urdf", str(tmp_path / "x.urdf")]) == 2
    assert "--no-consistent" in capsys.readouterr().err
