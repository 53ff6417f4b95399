"""The issue-13 battery: repair on generated logs of arms other than the D2R2.

Arms: the Sciavicco-Siciliano 2-link vertical arm, the PUMA 560's first three joints
(``robots/puma560_3link``, Armstrong-Khatib-Burdick inertias) and the 7-joint ``serial7``; cases
and their generation in :mod:`robust_drake.synthetic.battery` (8 s runs at 250 Hz, fit and
validation on different motions). Every case is repaired once (module cache) and asserted:

- ``none``: nothing claimed, nothing flagged;
- each library kind the simulator injects: the effect is named first, on its joint, its key
  parameter within the kind's stated tolerance (``simulated.HIDDEN_CASES``: 30 %, 40 % for the
  delay) and the validation RMS of the joint (all joints for global kinds and torque_scale)
  at least halved (payload: named from the rigid-body parameters' shift, halved against the
  URDF-only model);
- the delay: no battery arm's description declares a bus, so a ``time_delay`` has no physical
  source there and must not be claimed (``time_delay``: not claimed, nothing claimed with high
  confidence, the residual flagged); the same logs repaired against a copy of the arm whose
  description declares a bus (``time_delay_bus``) name it like any library kind;
- structure a diagnostic kind represents (periodic 3.1 / 0.73 Hz -> ``periodic_disturbance``,
  driver dead-zone -> ``dead_zone``; offered only where the residual's diagnostic fired): named
  on its joint, amplitude / threshold within ``battery.DIAGNOSTIC_KEY``'s tolerance, the
  frequency within 1 %, a periodic torque reported as a disturbance (``is_disturbance``), the
  joint's validation halved; nothing else claimed with high confidence, nothing misattributed;
- effects outside the library (backlash -- generator side, :mod:`robust_drake.synthetic.backlash`
  -- and the friction drift: ``friction_drift`` is offered only where the drift diagnostic fires,
  which it does on neither arm's 8 s runs): flagged as unexplained structure on its joint,
  nothing claimed with high confidence, no misattributed kind (``test_outside_library.MISATTRIBUTED``);
- log artefacts on the arm's ``battery.ARTEFACT_BASE`` case (jittered stamps, gaps, unequal file
  lengths, 1 kHz): the conditioning warning where there is one, the same effects claimed as on
  the clean 250 Hz log, the parameter within 10 % of the clean log's;
- every case: never worse -- no joint's validation RMS (nor replay RMS q) above the baseline's by
  more than the NEVER_WORSE_TOL margin beyond the paired block test's spread (the report's tests).
Cases measured failing are xfail(strict=False) with the measured reason (a failing case is
information: see BUILD_NOTES "battery"). The backlash block itself is checked against the
closed-form gap-crossing time.
"""

import math

import numpy as np
import pytest
from test_outside_library import EXPECTED_TEST, MISATTRIBUTED

from robust_drake.synthetic import battery as B
from robust_drake.synthetic.backlash import BacklashDrive, contact_parameters, dead_zone, transmitted_torque

pytest.importorskip("robust_drake.model_repair.pipeline")

ALL = ("none",) + B.LIBRARY_KINDS + ("time_delay_bus",) + B.OUTSIDE + B.ARTEFACTS
#: library kinds asserted named (the delay: with a declared bus, see the module docstring)
NAMED = tuple(k for k in B.LIBRARY_KINDS if k != "time_delay") + ("time_delay_bus",)
#: structure a diagnostic kind represents on these runs (drift: the diagnostic does not fire)
DIAGNOSED = ("periodic_fast", "periodic_slow", "dead_zone")
OUTSIDE = tuple(c for c in B.OUTSIDE if c not in DIAGNOSED)
#: per arm (serial7, 7 joints, runs a subset to keep the battery within its CI budget)
CASES = B.CASES
#: (arm, case, test) -> measured reason of a known failure (xfail, strict=False); measured
#: 2026-12-01 on branches battery13 and batfix (``benchmarks/battery_table.py``, table in
#: benchmarks/battery_table.md)
KNOWN: dict = {
    ("puma560_3link", "rotor_inertia", "library"):
        "named second: 0.4 kg m^2 on the shoulder lies in the rigid-body span; the nominal "
        "comparison's directed test names rotor_inertia[1] = 0.4005 (URDF-only shoulder 1.15 -> 0.047 "
        "N m, confidence moderate), but a moderate smooth_coulomb[2] (0.030 +- 0.010 N m on the elbow, "
        "elbow validation 0.0150 -> 0.0147 N m, replay -2 %) is claimed first (not the hidden effect): it "
        "comes with the IV switch (Hausman 44.5 > 38.9); with least squares only rotor_inertia[1] is "
        "claimed, and with the inertia set to 0 on the same stripped arm nothing is",
    ("siciliano_2link", "drift", "outside"):
        "not flagged on 8 s runs (the viscous coefficient of the elbow grows 1.6 N m s/rad per s); "
        "test_outside_library flags it on 12 s runs",
    ("puma560_3link", "spring", "library"):
        "not named: on the shoulder's +-1 rad swing about -0.8 rad a spring k q and a cogging of "
        "harmonic 2 (sin 2q, cos 2q, next to the gravity columns) are nearly collinear: held-out "
        "scores 0.1050 (spring[1]) and 0.1042 (position_dependent[1] h=2, chosen, confirmation gain "
        "51 % against the CV's 90 %); the replay guard then drops it; the 1 kHz, gap and split "
        "logs of the same runs pick the spring (the artefacts are checked on position_dependent)",
    ("puma560_3link", "asymmetric_coulomb", "library"):
        "not named: the shoulder's fitted asymmetry 2.37 N m exceeds the same fit's Coulomb level "
        "2.04 N m (truth 1.6 / 2.0), so the fit is inadmissible (a directional level would be "
        "negative); the step's winner, position_dependent[1] h=12, is not confirmed (-11 %)",
    ("serial7", "torque_scale", "library"):
        "not kept: the selection picks torque_scale[3] (held-out score 0.725, confirmation gain 76 %; "
        "the true joint 1 scores 0.835) and the URDF comparison keeps it on joint 3; it lowers the "
        "validation RMS (joint 1: 1.21 -> 0.45 N m) but the replay gets worse on joints 3-5, so the "
        "never-worse guard drops it and nothing is kept (replay joint 3 8.6e-3 -> 9.3e-3, joints 4-5 "
        "+14 % / +49 %, while joint 1 improves 1.13e-2 -> 8.3e-3 rad): a wrong-joint pick, rightly not kept",
    ("siciliano_2link", "dead_zone", "diagnosed"):
        "threshold off: named dead_zone[1] with d = 87.6 N m (true 60, +46 %) and share c = 0.69: the "
        "dead-band diagnostic's estimate is 97.4 N m on 8 s runs and the candidates are only 0.9 / "
        "1 / 1.1 x it, so the share compensates (the torque lost above the band, c d = 60.3 N m, is "
        "right within 1 %); validation of the elbow 29.1 -> 9.1 N m",
    ("puma560_3link", "dead_zone", "diagnosed"):
        "threshold off: named dead_zone[1] with d = 8.33 N m (true 6, +39 %, the dead-band "
        "diagnostic's own estimate) and share c = 0.72 (c d = 6.02 N m, right within 1 %); "
        "validation of the shoulder 3.0 -> 0.46 N m",
    ("serial7", "dead_zone", "diagnosed"):
        "threshold off: named dead_zone[1] with d = 5.0 N m (true 3, +67 %; the diagnostic's 4.54 "
        "x 1.1) and share c = 0.62 (c d = 3.09 N m, +3 %); validation of joint 1 1.94 -> 0.36 N m",
    ("serial7", "periodic_fast", "diagnosed"):
        "not named: the 3.1 Hz periodic diagnostic fires on joint 1 and periodic_disturbance[1] is "
        "offered (held-out score 0.899), but with 7 joints weighted equally the step's CV winner is "
        "a spurious position_dependent[5] h=6 (0.843), not confirmed (-0.7 %), and the selection "
        "stops there; the residual stays flagged on joint 1",
}

# issue 21 (branch selection): the selection's decisions became paired block tests at a stated level
# with a noise floor and a "degenerate" verdict; on these 8 s runs three cases named before lose
# their name (measured 2026-12-02, /tmp/selection/lost*.log of that branch):
KNOWN.update({
    ("siciliano_2link", "torque_offset", "library"):
        "named as configuration_dependent[1](terms=s0,c0) (issue 21's cable kind): over the 8 s run's "
        "range of q0, cos q0 and sin q0 span the 20 N m offset on joint 1 as well as the constant does, "
        "and the two-column kind wins the held-out ranking; the offset itself is not named",
    ("siciliano_2link", "stribeck", "library"):
        "not named (issue 21): stribeck[1] v=0.4 is the winner (held-out -77.6 % on joint 1) but its "
        "confirmation block (the last 1.6 s of the 8 s fit run: 4 blocks of 93 samples) gives "
        "-22.6 % [-100 %, +9.9 %], p = 0.064 >= 0.0125: not significant; the old rule accepted a "
        "5 % confirmation gain without its spread",
    ("siciliano_2link", "asymmetric_coulomb", "library"):
        "not named (issue 21): degenerate -- asymmetric_coulomb[1] and torque_offset[1] cut joint 1's "
        "held-out error by 77.4 % and 76.1 %, within each other's spread on the search rows: the "
        "data cannot rank them and neither is claimed",
    ("siciliano_2link", "gaps", "artefact"):
        "nothing claimed on the gapped log (issue 21): spring[1] (held-out -68.3 %) and a harmonic-2 "
        "cogging on joint 1 (-67.5 %) cannot be ranked on the four shorter segments (degenerate, as "
        "the PUMA's spring); the clean log names spring[1]",
    ("siciliano_2link", "unequal_files", "artefact"):
        "spring[1] not claimed on the split files (issue 21): spring[1] (held-out -90.9 %) and a "
        "harmonic-2 cogging on joint 1 cannot be ranked on the search rows of the 37 % / 63 % files "
        "(degenerate, as on the gapped log); the clean log names spring[1]",
})

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
    from robust_drake.forces import add_force_blocks, sum_into_plant

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


@pytest.mark.parametrize("arm,case", _params(NAMED, "library"))
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


@pytest.mark.parametrize("arm,case", _params(("rotor_inertia",), "span"))
def test_rotor_inertia_in_the_span_named_from_the_shift(arm, case, battery_dir):
    """The reflected rotor inertia of a model without the motors' inertia is named (by the
    residual or, where a free fit absorbs it, by the base-parameter shift against the URDF) with
    its value within the case's tolerance, and URDF + it at least halves the URDF-only model's
    validation error on its joint."""
    r = _row(arm, case, battery_dir)
    t = r["truth"]
    assert r["found"], (r["labels"], t)
    assert abs(r["estimate"] - r["true"]) <= t["rtol"] * abs(r["true"]), (r["estimate"], r["true"])
    if r["named_after"] is not None:
        j = t["joint"]
        assert r["named_after"][j] <= 0.5 * r["nominal_before"][j], (r["nominal_before"], r["named_after"])


@pytest.mark.parametrize("arm,case", _params(("time_delay",), "no_bus"))
def test_delay_without_a_declared_bus_is_not_claimed(arm, case, battery_dir):
    """The arm's description declares no bus: a delay has no physical source, so none is
    claimed, nothing else is claimed with high confidence in its place, and the residual the
    delay leaves is flagged (never-worse: :func:`test_never_worse`)."""
    r = _row(arm, case, battery_dir)
    assert not [k for k, _, _ in r["claimed"] if k == "time_delay"], r["labels"]
    assert all(c != "high" for _, _, c in r["claimed"]), r["claimed"]
    assert r["unexplained"], r["where"]


@pytest.mark.parametrize("arm,case", _params(DIAGNOSED, "diagnosed"))
def test_diagnosed_effect_named_by_its_kind(arm, case, battery_dir):
    """Named on its joint by the diagnostic kind, key parameter within ``battery.DIAGNOSTIC_KEY``'s
    tolerance of the simulator's (a periodic disturbance: amplitude 15 %, frequency 1 %, reported
    as a disturbance; a dead-zone: threshold 25 %), and the joint's validation RMS halved."""
    r = _row(arm, case, battery_dir)
    t = r["truth"]
    assert r["found"], (r["labels"], t)
    assert abs(r["estimate"] - r["true"]) <= t["rtol"] * abs(r["true"]), (r["estimate"], r["true"])
    p = r["found_parameters"]
    if t["kind"] == "periodic_disturbance":
        assert p["frequency"] == pytest.approx(t["parameters"]["frequency"], rel=B.FREQUENCY_RTOL), p
    assert r["is_disturbance"] is (t["kind"] == "periodic_disturbance"), r["is_disturbance"]
    j = t["joint"]
    assert r["after"][j] <= 0.5 * r["before"][j], (r["before"], r["after"])


@pytest.mark.parametrize("arm,case", _params(DIAGNOSED, "diagnosed_others"))
def test_diagnosed_effect_nothing_else_claimed(arm, case, battery_dir):
    """Besides the diagnostic kind on its joint: no misattributed kind, nothing with high
    confidence; and if the kind was not named, the residual is flagged on the joint."""
    r = _row(arm, case, battery_dir)
    t = r["truth"]
    others = [(k, j, c) for k, j, c in r["claimed"] if (k, j) != (t["kind"], t["joint"])]
    assert not [k for k, _, _ in others if k in MISATTRIBUTED], r["labels"]
    assert all(c != "high" for _, _, c in others), r["claimed"]
    if not r["found"]:
        rows = r["where"] + r["baseline_diagnostics"]
        assert r["unexplained"] and [w for w in rows if w.get("joint") == t["joint"]], rows


@pytest.mark.parametrize("arm,case", _params(OUTSIDE, "outside"))
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
    assert clean["claimed"], "the clean base case claims nothing: no answer to compare with"
    assert [(k, j) for k, j, _ in r["claimed"]] == [(k, j) for k, j, _ in clean["claimed"]], (r["labels"], clean["labels"])
    if clean["estimate"] is not None:
        assert r["estimate"] == pytest.approx(clean["estimate"], rel=0.10)


@pytest.mark.parametrize("arm,case", _params(ALL, "never_worse"))
def test_never_worse(arm, case, battery_dir):
    """Worse = worse beyond the paired block test's spread, by more than the NEVER_WORSE_TOL margin
    (issue 21). Before it this asserted every joint's point RMS within 1 %: e.g. puma560 none's
    replay joint 1 8.29e-5 -> 8.39e-5 rad (+1.2 %, 4 windows) or serial7's IV switch at +1.1 %
    on joint 6, changes inside their own spread."""
    r = _row(arm, case, battery_dir)
    before = np.array(r["before"])
    assert len(r["validate_change"]) == len(before)
    assert not [(j, t) for j, t in enumerate(r["validate_change"]) if t["worse"]]
    assert r["never_worse_validation"]
    if r["replay_before"] is not None:
        assert len(r["replay_change"]) == len(before)
        assert not [(j, t) for j, t in enumerate(r["replay_change"]) if t["worse"]]
        assert r["never_worse_replay"]
