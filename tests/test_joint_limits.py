"""References that respect the arm's joint position limits (issue 14).

A continuous MultibodyPlant does not enforce URDF position limits, so a reference outside them
"runs" and prints plausible numbers for a motion the arm cannot make.  Checked here: the limits
as Drake reads them, the default offset rule of the joint-space references, the one-line error
for a reference outside the limits (API and CLI), that the papers' arms (no limits) keep their
references, and that SP1 still beats PD on the Panda's default sine.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from robust_drake.diagram import ClosedLoop, ClosedLoopConfig, simulate
from robust_drake.errors import RobustDrakeError
from robust_drake.models import ArmSpec, JointLimits, get_arm, make_plant
from robust_drake.trajectories import LIMIT_MARGIN, check_within_limits, fit_in_limits, make_reference

# Franka Emika, "Robot and interface specifications" (Panda): q_min, q_max [rad], joints 0..6
FRANKA_Q_MIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
FRANKA_Q_MAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])


def test_limits_are_the_urdf_ones_as_drake_reads_them():
    """Panda: Franka's published ranges, named by the URDF's joints; continuous joints (serial7,
    D2R2) are unlimited; an explicit ``joint_limits`` wins over the URDF."""
    lim = get_arm("panda").position_limits()
    np.testing.assert_array_equal(lim.arrays()[0], FRANKA_Q_MIN)
    np.testing.assert_array_equal(lim.arrays()[1], FRANKA_Q_MAX)
    assert lim.names == tuple(f"joint{i}" for i in range(1, 8)) and set(lim.units) == {"rad"}
    for robot in ("serial7", "d2r2"):
        lo, hi = get_arm(robot).position_limits().arrays()
        assert np.all(lo == -np.inf) and np.all(hi == np.inf)
    own = JointLimits((-1.0, -1.0), (1.0, 1.0), ("a", "b"), ("rad", "rad"))
    arm = ArmSpec("d2r2", "d2r2.urdf", 2, (0.3, 0.3), False, "xy", joint_limits=own)
    assert arm.position_limits() is own
    assert JointLimits.from_plant(make_plant("panda")) == lim


def test_fit_in_limits_rule():
    """Hand-computed cases: inside -> untouched; outside but narrow enough -> centred, same
    amplitude; too wide -> centred and shrunk to (1 - 2 margin) of the range; one finite limit
    -> shifted inside it by margin x the motion's width."""
    lo = np.array([-0.5, -0.5, -2.0, 0.0, -0.5])
    hi = np.array([0.5, 0.5, 2.0, 1.0, 0.5])
    lower = np.array([-1.0, -3.0, -1.0, -np.inf, 0.2])
    upper = np.array([1.0, -0.1, 1.0, -0.5, np.inf])
    off, s, moved = fit_in_limits(lo, hi, lower, upper, margin=0.05)
    np.testing.assert_array_equal(moved, [False, True, True, True, True])
    np.testing.assert_allclose(s, [1.0, 1.0, 0.9 * 2.0 / 4.0, 1.0, 1.0])
    np.testing.assert_allclose(off, [0.0, -1.55, 0.0, -0.5 - 0.05 - 1.0, 0.2 + 0.05 + 0.5])
    # the fitted motions are inside
    assert np.all(off + s * lo >= lower) and np.all(off + s * hi <= upper)


def _panda_loop(**params):
    return ClosedLoop(ClosedLoopConfig(robot="panda", controller="pd", trajectory="sine", rate=1000.0,
                                       trajectory_params=params))


def test_panda_default_sine_is_inside_the_limits_and_is_eq49_about_the_middle():
    """Default sine on the Panda: joints 3 and 5 (q = 0 outside their ranges) swing about the
    middle of their ranges with JS eq. 49's amplitude 0.5 rad; the other joints about 0."""
    loop = _panda_loop()
    t = np.arange(0.0, 4.0 + 1e-9, 1e-3)
    q = loop.reference(t)[0]
    centre = np.zeros(7)
    centre[3] = (-3.0718 - 0.0698) / 2
    centre[5] = (-0.0175 + 3.7525) / 2
    np.testing.assert_allclose(q, centre + 0.5 * np.sin(math.pi * t)[:, None], rtol=0, atol=1e-12)
    assert np.all(q >= FRANKA_Q_MIN) and np.all(q <= FRANKA_Q_MAX)
    assert "joints [4, 6]" in loop.reference.params["limits"]  # numbered from 1


def test_too_wide_sine_is_shrunk_with_a_warning(caplog, monkeypatch):
    """amplitude 2 rad: joint 0 (+-2.8973) keeps it; joint 1 (+-1.7628) is centred at 0 and
    shrunk to 0.9 x 1.7628; joint 3 (range 3.002) centred and shrunk to 0.9 x 1.501."""
    import robust_drake.trajectories as T

    monkeypatch.setattr(T, "_LOGGED", set())  # messages are logged once per process
    with caplog.at_level(logging.WARNING, logger="robust_drake.trajectories"):
        ref = make_reference(get_arm("panda"), "sine", amplitude=2.0)
    amp = np.asarray(ref.params["amplitude"])
    assert amp[0] == 2.0 and amp[2] == 2.0 and amp[4] == 2.0
    np.testing.assert_allclose(amp[1], (1 - 2 * LIMIT_MARGIN) * 1.7628, rtol=1e-12)
    np.testing.assert_allclose(amp[3], (1 - 2 * LIMIT_MARGIN) * (3.0718 - 0.0698) / 2, rtol=1e-12)
    assert "scaled" in caplog.text and "joint4" in caplog.text
    q = ref(np.linspace(0, 4, 4001))[0]
    assert np.all(q >= FRANKA_Q_MIN) and np.all(q <= FRANKA_Q_MAX)


def test_explicit_offset_outside_the_limits_is_a_one_line_error():
    """offset 0 is used as given, so joint 4 (joint4) leaves [-3.072, -0.0698]: the error names
    the joint, its limits and the reference's range, and the parameters that move it."""
    with pytest.raises(RobustDrakeError) as e:
        _panda_loop(offset=0.0)
    msg = str(e.value)
    assert "\n" not in msg
    assert "joint 4 (joint4)" in msg and "[-3.072, -0.0698] rad" in msg and "[-0.5, 0.5] rad" in msg, msg
    assert "offset" in msg and "amplitude" in msg and "also joints [6]" in msg


def test_a_longer_run_is_checked_too():
    """A step at t0 = 1 s with offset 0 on a sign-limited joint: the build horizon (0.5 s) holds
    q_d = offset (inside), simulate(2 s) reaches the step, which leaves the range: refused."""
    offset = [0.0, 0.0, 0.0, -0.2, 0.0, 1.0, 0.0]
    loop = ClosedLoop(ClosedLoopConfig(robot="panda", controller="pd", trajectory="step", rate=1000.0,
                                       trajectory_params={"offset": offset, "amplitude": 0.3, "t0": 1.0,
                                                          "duration": 0.5}))
    with pytest.raises(RobustDrakeError, match=r"joint 4 \(joint4\).*over 2 s"):
        loop.simulate(2.0)


def test_check_within_limits_passes_a_reference_on_the_boundary():
    """Touching a limit is allowed; leaving it by 1e-9 is not."""
    lim = JointLimits((-1.0,), (1.0,), ("j",), ("rad",))
    arm = ArmSpec("x", "x", 1, (), False, None, joint_limits=lim)
    check_within_limits(make_reference(arm, "sine", amplitude=1.0, offset=0.0), lim, 4.0, 0.125)
    with pytest.raises(RobustDrakeError, match="joint 1 \\(j\\)"):
        check_within_limits(make_reference(arm, "sine", amplitude=1.0 + 1e-9, offset=0.0), lim, 4.0, 0.125)


def test_cli_out_of_range_reference(capsys):
    from robust_drake.cli import main

    argv = ["simulate", "--robot", "panda", "--controller", "pd", "--trajectory", "sine", "--rate", "1000",
            "--duration", "0.1", "--trajectory-param", "offset=0"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: reference 'sine'") and "\n" not in err and "Traceback" not in err, err
    assert "joint 4 (joint4)" in err
    assert main(argv[:-1] + ["offset"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err
    # the default: inside the limits, and the chosen offset is in the JSON
    import json

    assert main(argv[:-2] + ["--json"]) == 0
    ref = json.loads(capsys.readouterr().out)["reference"]
    np.testing.assert_allclose(ref["offset"], [0, 0, 0, -1.5708, 0, 1.8675, 0], atol=1e-12)


# -------------------------------------------------- the papers' arms: references unchanged
def _cubic(t, a):  # JS eq. 48, 0 -> a -> 0 in two 1 s cubics
    s = np.where(t < 1.0, t, t - 1.0)
    h = 3 * s ** 2 - 2 * s ** 3
    return np.where(t < 1.0, a * h, a * (1.0 - h))


def _crit(t, a, w):  # critically damped second-order step response
    return a * (1.0 - (1.0 + w * t) * np.exp(-w * t))


@pytest.mark.parametrize("robot", ["d2r2", "siciliano_2link", "serial7", "imi_scara"])
@pytest.mark.parametrize("trajectory,formula", [
    ("sine", lambda t: 0.5 * np.sin(math.pi * t)),        # JS eq. 49, a = 0.5 rad, omega = pi
    ("cpt", lambda t: _cubic(t, math.pi / 2)),            # JS eq. 48, 90 deg
    ("refmodel", lambda t: _crit(t, math.pi / 2, 3.5)),   # JS eq. 47, omega = 3.5
    ("step", lambda t: _crit(t, 0.5, 10.0)),              # CI 5.2 filtered step
])
def test_default_references_of_unlimited_arms_are_unchanged(robot, trajectory, formula):
    """q_d of the loop's reference (the one it runs) against the formulas, every joint."""
    loop = ClosedLoop(ClosedLoopConfig(robot=robot, controller="pd", trajectory=trajectory, rate=500.0))
    t = np.arange(0.0, loop.reference.duration + 1e-9, 2e-3)
    q = np.asarray(loop.reference(t)[0])
    np.testing.assert_allclose(q, np.repeat(formula(t)[:, None], loop.n, axis=1), rtol=1e-13, atol=1e-14)
    assert "limits" not in loop.reference.params and not np.any(loop.reference.params["offset"])


# -------------------------------------------------- SP1 vs PD on the Panda's default sine
def test_sp1_beats_pd_on_the_panda_default_sine():
    """1 kHz, default sine (inside the limits), Gaz et al. friction in the plant, 20-bit
    encoder, Franka's torque limits; same K = 50 diag M(q_d(0)), Lambda = 20 for both.  After
    0.75 s every joint's largest error is smaller under SP1 (all below 0.01 rad)."""
    loop0 = _panda_loop()
    q0 = loop0.reference(0.0)[0]
    plant = make_plant("panda")
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, q0)
    K = (50.0 * np.diag(plant.CalcMassMatrix(ctx))).tolist()
    common = dict(robot="panda", trajectory="sine", rate=1000.0, duration=1.5,
                  encoder_resolution=2 * np.pi / 2 ** 20, torque_limit=[87.0] * 4 + [12.0] * 3,
                  effects=[("sigmoid_friction", {})])
    runs = {c: simulate(ClosedLoopConfig(controller=c, controller_params=dict(p, K=K, Lambda=20.0), **common))
            for c, p in (("pd", {}), ("sp1", {"epsilon": 1.0}))}
    sp, pd = runs["sp1"], runs["pd"]
    assert not sp.diverged and not pd.diverged
    assert np.all(sp.q_d >= FRANKA_Q_MIN) and np.all(sp.q_d <= FRANKA_Q_MAX)
    late = sp.t > 0.75  # after the start-up transient (the arm starts at rest, qd_d(0) = 0.5 pi rad/s)
    e = {k: np.abs(r.q - r.q_d)[late] for k, r in runs.items()}
    assert np.all(e["sp1"].max(axis=0) < e["pd"].max(axis=0)) and e["sp1"].max() < 0.01, e["sp1"].max(axis=0)
    assert np.sqrt(np.mean(e["sp1"] ** 2)) < 0.2 * np.sqrt(np.mean(e["pd"] ** 2))  # measured 0.0024 vs 0.033 rad
    assert np.all(sp.q >= FRANKA_Q_MIN) and np.all(sp.q <= FRANKA_Q_MAX)


def test_identification_excitation_outside_the_limits_is_refused():
    """The Fourier excitation of ``simulate_experiment`` about q = 0 on the Panda leaves the
    sign-limited joints: refused before simulating, naming the excitation's parameters (the
    logs-to-control excitation swings about the middle of each range instead)."""
    from robust_drake.experiments.logs_to_control import excitation_for
    from robust_drake.synthetic.simulated import simulate_experiment

    with pytest.raises(RobustDrakeError, match=r"excitation.*joint ([46]) \(joint\1\).*'offset'"):
        simulate_experiment("panda", duration=2.0, excitation=dict(amplitude=1.0, torque_limit=None),
                            coulomb=0.1, viscous=0.01)
    exc = excitation_for("panda")
    assert np.all(np.asarray(exc["offset"]) - np.asarray(exc["amplitude"]) >= FRANKA_Q_MIN)
    assert np.all(np.asarray(exc["offset"]) + np.asarray(exc["amplitude"]) <= FRANKA_Q_MAX)
