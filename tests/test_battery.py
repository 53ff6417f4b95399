"""The issue-13 battery: repair on generated logs of arms other than the D2R2.

Arms: the Sciavicco-Siciliano 2-link vertical arm, the PUMA 560's first three joints
(``robots/puma560_3link``, Armstrong-Khatib-Burdick inertias) and the 7-joint ``serial7``; cases
and their generation in :mod:`robust_drake.model_repair.battery` (8 s runs at 250 Hz, fit and
validation on different motions). Every case is repaired once (module cache) and asserted:

- ``none``: nothing claimed, nothing flagged;
- each library kind the simulator injects: the effect is named first, on its joint, its key
  parameter within the kind's stated tolerance (``simulated.HIDDEN_CASES``: 30 %, 40 % for the
  delay) and the validation RMS of the joint (all joints for global kinds and torque_scale)
  at least halved (payload: named from the rigid-body parameters' shift, halved against the
  URDF-only model);
- each effect outside the library (periodic 3.1 / 0.73 Hz, driver dead-zone, friction drift,
  backlash -- generator side, :mod:`robust_drake.model_repair.backlash`): flagged as
  unexplained structure on its joint, nothing claimed with high confidence, no misattributed
  kind (``test_outside_library.MISATTRIBUTED``);
- log artefacts on the arm's ``battery.ARTEFACT_BASE`` case (jittered stamps, gaps, unequal file
  lengths, 1 kHz): the conditioning warning where there is one, the same effects claimed as on
  the clean 250 Hz log, the parameter within 10 % of the clean log's;
- every case: never worse -- each joint's validation RMS after <= before x (1 + NEVER_WORSE_TOL)
  and the replay not worse by more than the same tolerance.
Cases measured failing are xfail(strict=False) with the measured reason (a failing case is
information: see BUILD_NOTES "battery"). The backlash block itself is checked against the
closed-form gap-crossing time.
"""

import math

import numpy as np
import pytest
from test_outside_library import EXPECTED_TEST, MISATTRIBUTED

from robust_drake.model_repair import battery as B
from robust_drake.model_repair.backlash import BacklashDrive, contact_parameters, dead_zone, transmitted_torque
from robust_drake.model_repair.stages import NEVER_WORSE_TOL

pytest.importorskip("robust_drake.model_repair.pipeline")

ALL = ("none",) + B.LIBRARY_KINDS + B.OUTSIDE + B.ARTEFACTS
#: per arm (serial7, 7 joints, runs a subset to keep the battery within its CI budget)
CASES = B.CASES
#: (arm, case, test) -> measured reason of a known failure (xfail, strict=False); measured
#: 2026-12-01 on branch battery13 (``benchmarks/battery_table.py``, table in BUILD_NOTES)
_IV = ("serial7: nothing (or only moderate effects) kept, but the final estimator differs from the "
       "least-squares baseline and joint 6 validates 1.6-1.7 % worse (periodic: joint 4 +1.5 % too); the "
       "IV switch is judged by the replay, not yet by the per-joint torque rule (issue 13, as in "
       "test_outside_library)")
KNOWN: dict = {
    ("siciliano_2link", "stribeck", "library"):
        "not claimed: a 32 N m Stribeck excess (v_s 0.4 rad/s) on the elbow raises its validation RMS "
        "only from the 2.7 N m no-effect floor to 4.7 N m; the selection adds nothing",
    ("siciliano_2link", "presliding_friction", "library"):
        "not claimed: Dahl friction 40 N m (x0 0.01 rad) on the shoulder, validation 13.4 N m against "
        "the 4.5 N m no-effect floor; the selection adds nothing",
    ("puma560_3link", "stribeck", "library"):
        "not claimed at 3.2 N m on the shoulder (with effect_scale 20, 1.6 N m, it was named with 1 % "
        "error); the larger breakaway probably makes the joint stick (stiction: demo13's part)",
    ("puma560_3link", "load_dependent_friction", "library"):
        "not claimed: mu = 0.1 on the waist (named with 1 % error before the shoulder/elbow swing was "
        "widened to +-1 rad)",
    ("puma560_3link", "rotor_inertia", "library"):
        "absorbed: 0.4 kg m^2 on the shoulder of a model without rotor inertia lies in the rigid-body "
        "span (free-fit validation 0.047 N m = the no-effect floor, URDF-only 1.15 N m), the nominal "
        "comparison does not name it, and a moderate smooth_coulomb[2] is claimed instead",
    ("puma560_3link", "presliding_friction", "library"):
        "not claimed: Dahl friction 4 N m (x0 0.01 rad) on the waist",
    ("serial7", "time_delay", "library"):
        "not claimed: a 12 ms delay on all joints raises joint 1's validation RMS from the 0.108 N m "
        "floor to 0.243 N m; the selection adds nothing",
    ("siciliano_2link", "drift", "outside"):
        "not flagged on 8 s runs (the viscous coefficient of the elbow grows 1.6 N m s/rad per s); "
        "test_outside_library flags it on 12 s runs",
    ("siciliano_2link", "backlash", "outside"):
        "not flagged: the elbow's validation RMS is 31.7 N m against the 2.7 N m no-effect floor, yet "
        "no diagnostic (periodic, drift, dead-band, state dependence, generalization) fires",
    ("puma560_3link", "backlash", "outside"):
        "not flagged: the waist's validation RMS is 1.25 N m against the 0.091 N m no-effect floor, "
        "yet no diagnostic fires",
    ("serial7", "backlash", "outside"):
        "not flagged: joint 1's validation RMS is 0.51 N m against the 0.108 N m no-effect floor, yet "
        "no diagnostic fires",
    ("serial7", "periodic_fast", "never_worse"): _IV,
    ("serial7", "dead_zone", "never_worse"): _IV,
}

_ROWS: dict = {}


@pytest.fixture(scope="module")
def battery_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("battery")


def _row(arm, case, battery_dir):
    if (arm, case) not in _ROWS:
        _ROWS[(arm, case)] = B.run_case(arm, case, str(battery_dir / arm / case))
    return _ROWS[(arm, case)]


def _params(cases, test):
    out = []
    for arm, names in CASES.items():
        for c in names:
            if c not in cases:
                continue
            reason = KNOWN.get((arm, c, test))
            marks = [pytest.mark.xfail(strict=False, reason=reason)] if reason else []
            marks += [pytest.mark.slow] if arm == "serial7" else []  # 7 joints: 15-50 s a case
            out.append(pytest.param(arm, c, marks=marks, id=f"{arm}-{c}"))
    return out


# ------------------------------------------------------------------------------ backlash block
def test_backlash_transmits_nothing_in_the_gap_and_never_pulls():
    b, k, c = 0.01, 1e4, 20.0
    delta = np.array([-0.02, -0.01, -0.005, 0.0, 0.004, 0.01, 0.015])
    np.testing.assert_allclose(dead_zone(delta, b), [-0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.005], rtol=0, atol=1e-15)
    t = transmitted_torque(delta, np.zeros_like(delta), b, k, c)
    assert np.all(t[1:6] == 0.0) and t[0] == pytest.approx(-100.0) and t[-1] == pytest.approx(50.0)
    # teeth separating fast: the damper would pull, contact cannot
    assert transmitted_torque(0.0101, -5.0, b, k, c) == 0.0
    assert transmitted_torque(0.0101, +5.0, b, k, c) == pytest.approx(k * 1e-4 + c * 5.0)


_ONE_LINK = """<?xml version="1.0"?>
<robot name="one_link" xmlns:drake="http://drake.mit.edu">
  <link name="world"/>
  <link name="link1"><inertial><origin xyz="0.3 0 0"/><mass value="2.0"/>
    <inertia ixx="0.01" iyy="0.2" izz="0.2" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="joint1" type="continuous"><parent link="world"/><child link="link1"/>
    <axis xyz="0 0 1"/></joint>
  <transmission name="t1"><type>transmission_interface/SimpleTransmission</type>
    <joint name="joint1"/><actuator name="m1"/></transmission>
</robot>
"""


def test_backlash_gap_is_crossed_in_the_free_flight_time(tmp_path):
    """One link on a vertical axis (J_l = 0.2 + 2 x 0.3^2 = 0.38 kg m^2, no gravity torque), a
    drive with motor inertia J_m = 0.5 kg m^2 and gap half-width b = 0.01 rad. A torque of -2 N m
    pushes the teeth together on one flank; at t1 = 0.3 s it steps to +2 N m. The motor alone
    then crosses the gap: delta goes from -b to +b in t_c = sqrt(2 (2 b) J_m / tau) = 0.1 s,
    while the link coasts at the velocity it had (no drive torque reaches it)."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource, VectorLogSink
    from pydrake.trajectories import PiecewisePolynomial

    from robust_drake.models import add_arm
    from robust_drake.systems.forces import add_force_blocks, sum_into_plant

    urdf = tmp_path / "one_link.urdf"
    urdf.write_text(_ONE_LINK)
    Jm, b, tau0, t1 = 0.5, 0.01, 2.0, 0.3
    builder = DiagramBuilder()
    plant = add_arm(builder, str(urdf))[0]
    src = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(
        [0.0, t1, 1.0], np.array([[-tau0, tau0, tau0]]))))
    k, c = contact_parameters(Jm, 200.0, 0.5)
    bl = BacklashDrive(1, 0, b, Jm, k, c)
    ports = add_force_blocks(builder, plant, [bl], src.get_output_port())
    sum_into_plant(builder, plant, [src.get_output_port()] + ports)
    log_gap = builder.AddSystem(VectorLogSink(1, 1e-4))
    log_x = builder.AddSystem(VectorLogSink(2, 1e-4))
    builder.Connect(bl.GetOutputPort("gap"), log_gap.get_input_port())
    builder.Connect(plant.get_state_output_port(), log_x.get_input_port())
    sim = Simulator(builder.Build())
    sim.get_mutable_integrator().set_maximum_step_size(1e-4)
    sim.Initialize()
    sim.AdvanceTo(0.5)
    ctx = sim.get_context()
    t = log_gap.FindLog(ctx).sample_times()
    gap = log_gap.FindLog(ctx).data()[0]
    v = log_x.FindLog(ctx).data()[1]
    assert gap[0] == pytest.approx(-b)  # initialised on the flank the first torque pushes
    # crossing: from leaving the -b flank to reaching +b (compression of the stiff teeth ~ tau/k)
    left = t[(t > t1) & (gap > -b)][0]
    reached = t[(t > t1) & (gap >= b)][0]
    t_c = math.sqrt(2 * 2 * b * Jm / tau0)
    assert reached - t1 == pytest.approx(t_c, rel=0.05), (left, reached, t_c)
    # the link coasts meanwhile: its velocity changes by much less than the drive would give it
    inside = (t > left + 0.005) & (t < reached - 0.005)
    assert inside.sum() > 500  # ~0.09 s of samples at 0.1 ms
    J_link = 0.2 + 2.0 * 0.3 ** 2
    dv = np.ptp(v[inside])
    assert dv < 0.02 * tau0 / J_link * t_c, dv
    assert v[t < t1][-1] < 0  # it was moving the other way before the step


# ------------------------------------------------------------------------------ the battery
@pytest.mark.parametrize("arm,case", _params(("none",), "none"))
def test_no_effect_nothing_claimed(arm, case, battery_dir):
    r = _row(arm, case, battery_dir)
    assert r["claimed"] == [], r["labels"]
    assert not r["unexplained"], r["where"]


def _joints(r):
    t = r["truth"]
    n = len(r["before"])
    return list(range(n)) if t["joint"] is None or t["kind"] == "torque_scale" else [t["joint"]]


def _rms(xs, joints):
    return math.sqrt(sum(xs[j] ** 2 for j in joints))


@pytest.mark.parametrize("arm,case", _params(B.LIBRARY_KINDS, "library"))
def test_library_effect_named_recovered_and_halved(arm, case, battery_dir):
    r = _row(arm, case, battery_dir)
    t = r["truth"]
    assert r["found"] and r["first"] == t["kind"], (r["labels"], t)
    assert abs(r["estimate"] - r["true"]) <= t["rtol"] * abs(r["true"]), (r["estimate"], r["true"])
    if r["named_after"] is not None:  # payload: URDF + payload against URDF only
        before, after = r["nominal_before"], r["named_after"]
    else:
        before, after = r["before"], r["after"]
    js = _joints(r)
    assert _rms(after, js) <= 0.5 * _rms(before, js), (before, after)
    assert all(c != "high" for _, _, c in r["claimed"][1:]), r["claimed"]


@pytest.mark.parametrize("arm,case", _params(B.OUTSIDE, "outside"))
def test_outside_effect_flagged_and_not_claimed(arm, case, battery_dir):
    r = _row(arm, case, battery_dir)
    j = r["truth"]["joint"]
    test = EXPECTED_TEST.get(case)  # backlash: whichever diagnostic fires, on its joint
    assert not [lbl for (k, _, _), lbl in zip(r["claimed"], r["labels"]) if k in MISATTRIBUTED], r["labels"]
    assert all(c != "high" for _, _, c in r["claimed"]), r["claimed"]
    assert r["unexplained"], r["where"]
    rows = r["where"] + r["baseline_diagnostics"]

    def fits(w):  # a drift may also show as the residual's dependence on time
        return test is None or w.get("test") == test or (
            test == "drift" and w.get("test") == "state_dependence" and w.get("variable") == "t")
    assert [w for w in rows if w.get("joint") == j and fits(w)], rows


ARTEFACT_WARNING = {"jitter": "scatter around a fixed rate", "gaps": "logging gap"}


@pytest.mark.parametrize("arm,case", _params(B.ARTEFACTS, "artefact"))
def test_log_artefact_warned_and_same_answer(arm, case, battery_dir):
    r = _row(arm, case, battery_dir)
    clean = _row(arm, B.ARTEFACT_BASE[arm], battery_dir)
    if case in ARTEFACT_WARNING:
        assert any(ARTEFACT_WARNING[case] in w for w in r["warnings"]), r["warnings"]
    assert [(k, j) for k, j, _ in r["claimed"]] == [(k, j) for k, j, _ in clean["claimed"]], (r["labels"], clean["labels"])
    if clean["estimate"] is not None:
        assert r["estimate"] == pytest.approx(clean["estimate"], rel=0.10)


@pytest.mark.parametrize("arm,case", _params(ALL, "never_worse"))
def test_never_worse(arm, case, battery_dir):
    r = _row(arm, case, battery_dir)
    before, after = np.array(r["before"]), np.array(r["after"])
    assert np.all(after <= before * (1 + NEVER_WORSE_TOL)), (before, after)
    if r["replay_before"] is not None:
        rb, ra = np.array(r["replay_before"]), np.array(r["replay_after"])
        assert np.all(ra <= rb * (1 + NEVER_WORSE_TOL)), (rb, ra)
