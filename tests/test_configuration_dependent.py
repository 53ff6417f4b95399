"""The ``configuration_dependent`` kind (a torque on joint j that is a function of the other
joints' angles: cables, hoses, coupled springs) and the cogging grid's 1-12 harmonics (issue 21).

Truths used: the block adds f_e,j = -sum c_i phi_i(q) (eq. CD1 of the kind's docstring), written
out here by hand; the gravity torque of the first joint of a vertical-plane double pendulum
contains a sin q_0 + b cos q_0 (its own link), that of the second joint only functions of
q_0 + q_1; a cable on the PUMA's elbow simulated with known coefficients is recovered; an arm
without it gets nothing; a 5/rev cogging is told from its 4/rev and 6/rev neighbours.
"""

import math
import os

import numpy as np
import pytest

import robust_drake as rd
from robust_drake.errors import RobustDrakeError
from robust_drake.identification.least_squares import load_regressor
from robust_drake.effects import (
    EFFECTS, PhysicalContext, PositionDependent, all_candidates, gravity_aliases, make_effect,
)
from robust_drake.model_repair.residual import configuration_dependence
from robust_drake.synthetic.simulated import simulate_experiment
from robust_drake.synthetic.simulated_cases import ARMS

PUMA = "puma560_3link"
C1 = "dfki_double_pendulum_c1"
#: the hidden cable on the PUMA's elbow (index 2, joint 3): the motor supplies
#: 1.2 sin q1 - 0.8 cos q1 + 0.6 sin q2 + 1.0 cos q2 [N m] (torque noise 0.05 N m); term tokens
#: and coefficient names number joints from 1 like every label (README, "Joint numbering")
CABLE = {"terms": "s1,c1,s2,c2", "sin(q1)": 1.2, "cos(q1)": -0.8, "sin(q2)": 0.6, "cos(q2)": 1.0}


def _cable_by_hand(q):
    """What the plant receives from the cable on joint 3 (index 2), from CABLE's numbers (eq. CD1)."""
    return -(1.2 * math.sin(q[0]) - 0.8 * math.cos(q[0]) + 0.6 * math.sin(q[1]) + 1.0 * math.cos(q[1]))


def _eval_block(block, x):
    ctx = block.CreateDefaultContext()
    block.GetInputPort("state").FixValue(ctx, np.asarray(x, float))
    return block.GetOutputPort("generalized_force").Eval(ctx)


def test_block_equals_minus_columns_times_coefficients_and_the_physics():
    eff = make_effect("configuration_dependent", 2, terms=CABLE["terms"])
    coef = eff.coef_from_parameters(CABLE, 3)
    blk = eff.block(3, CABLE)
    assert blk.get_input_port(0).get_name() == "state" and blk.get_input_port(0).size() == 6
    assert blk.get_output_port(0).get_name() == "generalized_force"
    rng = np.random.default_rng(3)
    X = np.hstack([rng.uniform(-3, 3, (20, 3)), rng.uniform(-2, 2, (20, 3))])
    cols = eff.evaluate_columns(X[:, :3])
    for i, x in enumerate(X):
        f = _eval_block(blk, x)
        np.testing.assert_allclose(f, -(cols[i] @ coef), atol=1e-12)
        np.testing.assert_allclose(f, [0.0, 0.0, _cable_by_hand(x)], atol=1e-12)
    back = eff.parameters(coef, q=X[:, :3])
    for k in ("sin(q1)", "cos(q1)", "sin(q2)", "cos(q2)"):
        assert back[k] == pytest.approx(CABLE[k], abs=1e-12)
    by_hand = np.array([_cable_by_hand(x) for x in X])
    assert back["explained_rms"] == pytest.approx(np.sqrt(np.mean(by_hand**2)))
    assert back["peak"] == pytest.approx(np.abs(by_hand).max())


def test_prismatic_terms_and_bad_input():
    eff = make_effect("configuration_dependent", 0, terms="l2,p2,s3")
    q = np.array([[0.3, 0.2, 1.0]])
    np.testing.assert_allclose(eff.evaluate_columns(q)[0, 0], [0.2, 0.04, math.sin(1.0)])
    assert len(eff.column_names(3)) == 3 and eff.num_coef(3) <= 2 * 3 + 1
    for bad in (dict(joint=None, terms="s1"), dict(joint=1, terms="s2,c1"), dict(joint=1, terms="s0"),
                dict(joint=1, terms="x1"), dict(joint=1, terms="")):
        with pytest.raises(RobustDrakeError):
            make_effect("configuration_dependent", **bad)
    with pytest.raises(RobustDrakeError, match="joint 4 of a 3-joint arm"):
        make_effect("configuration_dependent", 0, terms="s4").evaluate_columns(q)


def test_gravity_aliases_are_the_first_links_own_gravity():
    """C.1 in its vertical plane: joint 1 carries its own link's a sin q1 + b cos q1 (aliases of
    s1, c1), not a function of q2 alone; joint 2's gravity is a function of q1 + q2 only."""
    reg = load_regressor(C1)
    assert gravity_aliases(reg, 0, ["s1", "c1", "s2", "c2"]) == ["s1", "c1"]
    assert gravity_aliases(reg, 1, ["s1", "c1"]) == []


def test_offered_only_where_another_joints_angle_explains_the_residual():
    # rows: "joint" the 0-based index, "variable" the signal named from 1 (q1 = index 0's angle)
    rows = [{"joint": 2, "variable": "q1", "eta2": 0.4, "p": 1e-30},
            {"joint": 1, "variable": "q2", "eta2": 0.5, "p": 1e-30},  # its own angle: not this kind
            {"joint": 0, "variable": "qd2", "eta2": 0.5, "p": 1e-30},  # a velocity: not this kind
            {"joint": 0, "variable": "q3", "eta2": 0.1, "p": 0.004}]  # above 0.01 / 6
    got = configuration_dependence(rows, 3, alpha=0.01)
    assert [(r["joint"], r["variable"]) for r in got] == [(2, "q1")]
    assert all_candidates(3, kinds=["configuration_dependent"]) == []
    cands = all_candidates(3, kinds=["configuration_dependent"], diagnostics=got, robot=PUMA)
    assert [(c.joint, c.shape["terms"]) for c in cands] == [(2, "s1,c1,s2,c2")]


def test_admissible_peak_within_the_torque_range():
    eff = make_effect("configuration_dependent", 2, terms="s1,c1,s2,c2")
    q = np.random.default_rng(0).uniform(-2, 2, (200, 3))
    ctx = PhysicalContext(tau_max=(50.0, 50.0, 1.0), configurations=q)
    assert eff.admissible(CABLE, ctx)  # peak ~2 N m > 1 N m
    assert eff.admissible(CABLE, PhysicalContext(tau_max=(50.0, 50.0, 10.0), configurations=q)) == ""


def _puma_case(out, effects, seed=0):
    kw = {k: v for k, v in ARMS[PUMA].items() if k not in ("effect_scale", "drift_scale")}
    paths = []
    for role, sd in (("fit", seed), ("validate", seed + 1)):
        path = os.path.join(out, f"{role}.csv")
        simulate_experiment(PUMA, effects, duration=12.0, rate_hz=250.0, seed=sd, out_csv=path, **kw)
        paths.append(path)
    return paths


@pytest.fixture(scope="module")
def cable(tmp_path_factory):
    fit, val = _puma_case(str(tmp_path_factory.mktemp("cable")), [("configuration_dependent", 2, CABLE)])
    return rd.repair(fit, robot=PUMA, validate=val, plots=False, replay=False)


@pytest.fixture(scope="module")
def no_cable(tmp_path_factory):
    fit, val = _puma_case(str(tmp_path_factory.mktemp("none")), [])
    return fit, rd.repair(fit, robot=PUMA, validate=val, plots=False, replay=False)


def test_cable_on_the_elbow_is_named_with_its_coefficients(cable):
    rep = cable.report
    offered = [r for r in rep["residual"]["baseline"]["configuration_dependence"] if r["joint"] == 2]
    assert {r["variable"] for r in offered} & {"q1", "q2"}, offered
    named = [e for e in rep["effects"] if e["kind"] == "configuration_dependent"]
    assert [e["joint"] for e in named] == [2], [e["label"] for e in rep["effects"]]
    p = named[0]["parameters"]
    for k in ("sin(q1)", "cos(q1)", "sin(q2)", "cos(q2)"):
        assert p[k] == pytest.approx(CABLE[k], rel=0.1), (k, p)
    before, after = np.asarray(rep["baseline"]["rms_validate"]), np.asarray(rep["final"]["rms_validate"])
    assert after[2] < 0.2 * before[2], (before, after)  # the cable was ~0.9 N m RMS, noise 0.05
    assert np.all(after <= before * 1.01), (before, after)


def test_arm_without_the_cable_gets_none_even_when_offered_on_every_joint(no_cable):
    fit, res = no_cable
    assert "configuration_dependent" not in [e["kind"] for e in res["effects"]], res["effects"]
    # forced into the pool on every joint (as if the residual test had fired): still not chosen
    from robust_drake.identification.data import load
    from robust_drake.model_repair.selection import ColumnCache, forward_select

    data = load(fit, robot=PUMA)
    cands = all_candidates(3, kinds=["configuration_dependent"], robot=PUMA,
                           diagnostics=[{"test": "configuration_dependence", "joint": j} for j in range(3)])
    assert len(cands) == 3
    sel = forward_select(ColumnCache(data, load_regressor(PUMA)), cands,
                         context=PhysicalContext.from_data(data, PUMA))
    assert sel.chosen == [], [s.reason for s in sel.steps]


def test_cogging_grid_covers_1_to_12_and_finds_a_5_per_rev_cogging(tmp_path):
    assert sorted(g["harmonic"] for g in PositionDependent.shape_grid) == list(range(1, 13))
    true = {"amplitude": 0.06, "phase": 0.5, "harmonic": 5}
    paths = []
    for role, sd in (("fit", 0), ("validate", 1)):
        path = str(tmp_path / f"{role}.csv")
        simulate_experiment(C1, [("position_dependent", 1, true)], duration=12.0, seed=sd, out_csv=path,
                            coulomb=(0.02, 0.01))
        paths.append(path)
    res = rd.repair(paths[0], robot=C1, validate=paths[1], effects="position_dependent", plots=False,
                    replay=False, instruments=False, nominal=False)
    cog = [e for e in res["effects"] if e["kind"] == "position_dependent"]
    assert [(e["joint"], e["parameters"]["harmonic"]) for e in cog] == [(1, 5)], [e["label"] for e in cog]
    assert cog[0]["parameters"]["amplitude"] == pytest.approx(0.06, rel=0.15)
    assert "configuration_dependent" in EFFECTS


def test_a_spring_on_the_joints_own_angle_stays_a_spring(tmp_path):
    """The residual of the elbow then also depends on the other angles along the motion (the kind
    is offered), but its own angle explains it: ``spring[2]`` is named, not this kind."""
    fit, val = _puma_case(str(tmp_path), [("spring", 2, {"stiffness": 3.0})])
    res = rd.repair(fit, robot=PUMA, validate=val, plots=False, replay=False)
    assert res.report["residual"]["baseline"]["configuration_dependence"]  # offered
    assert [(e["kind"], e["joint"]) for e in res["effects"]] == [("spring", 2)], [e["label"] for e in res["effects"]]
    assert res["effects"][0]["parameters"]["stiffness"] == pytest.approx(3.0, rel=0.05)


def test_on_every_joint_each_joint_gets_its_own_basis_and_coefficients():
    eff = make_effect("configuration_dependent", None)
    assert eff.num_coef(3) == 3 * 4
    coef = np.arange(1.0, 13.0) / 10
    rng = np.random.default_rng(5)
    X = np.hstack([rng.uniform(-3, 3, (4, 3)), np.zeros((4, 3))])
    blk = eff.block(3, eff.parameters(coef))
    for x in X:
        q = x[:3]
        phi = {0: [math.sin(q[1]), math.cos(q[1]), math.sin(q[2]), math.cos(q[2])],
               1: [math.sin(q[0]), math.cos(q[0]), math.sin(q[2]), math.cos(q[2])],
               2: [math.sin(q[0]), math.cos(q[0]), math.sin(q[1]), math.cos(q[1])]}
        by_hand = [-np.dot(coef[4 * j:4 * j + 4], phi[j]) for j in range(3)]
        np.testing.assert_allclose(_eval_block(blk, x), by_hand, atol=1e-12)
    from robust_drake.excitation.information import check_effect_kinds
    assert check_effect_kinds(["configuration_dependent"], 3)[0].num_coef(3) == 12
