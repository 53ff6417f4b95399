"""Replay measured torques through the (augmented) Drake plant on short horizons.

For every window [t_k, t_k + H] (``horizon``) the plant state is reset to the measured
(filtered) q, qd at t_k and the measured torque (first-order hold between samples) drives::

    MultibodyPlant(robot [+ plant-modifying effects], inertias = identified)  <-- tau + friction + effect blocks

The position error q_sim - q_measured over each window is the replay error; ``before`` uses the
baseline (rigid body + Coulomb + viscous), ``after`` the repaired model with its effect blocks
(``effects.effect_force_blocks``), all summed by ``forces.sum_into_plant``. Friction in
the plant is ``systems.friction.CoulombViscousFriction`` with the smooth sign tanh(qd / v_eps)
(v_eps = ``REPLAY_V_EPS`` = 0.05 rad/s) so an error-controlled integrator can step through
reversals.

Rigid-body inertias: the physically consistent estimate (``consistency``) written into the plant
context when available; otherwise the URDF's nominal inertias (said in the result).
"""

from __future__ import annotations

import numpy as np

from robust_drake.identification.data import IdentData

DEFAULT_HORIZON = 0.2  # s
MAX_WINDOWS = 30
REPLAY_V_EPS = 0.05  # rad/s, tanh width of the replay friction (kept from the first replay code)


def build_replay_diagram(robot, data: IdentData, coulomb, viscous, effects=(), inertias=None,
                         sample_period=None):
    """Diagram: tau source (first-order hold of data.tau) + friction + effect blocks -> plant,
    through the one force path (:mod:`robust_drake.forces`; effect blocks with a ``tau``
    input see the measured torque).

    ``effects`` = [(Effect, parameters), ...]; ``inertias`` = (body_names, pi) or None (set in
    the context by :func:`replay`)."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource
    from pydrake.trajectories import PiecewisePolynomial

    from robust_drake.effects import effect_force_blocks, load_plant
    from robust_drake.forces import add_force_blocks, sum_into_plant
    from robust_drake.systems.friction import CoulombViscousFriction

    builder = DiagramBuilder()
    plant = load_plant(robot, [(e, p) for e, p in effects if e.modifies_plant], builder=builder)
    n = plant.num_velocities()
    traj = PiecewisePolynomial.FirstOrderHold(data.t, data.tau.T)
    src = builder.AddSystem(TrajectorySource(traj))
    src.set_name("measured_tau")
    fric = CoulombViscousFriction(n, coulomb, viscous, REPLAY_V_EPS, nonnegative=False)
    fric.set_name("identified_friction")
    blocks = [fric] + effect_force_blocks(effects, n, sample_period or data.dt)
    tau = src.get_output_port(0)
    sum_into_plant(builder, plant, [tau] + add_force_blocks(builder, plant, blocks, tau))
    if plant.get_actuation_input_port().size() > 0:
        from pydrake.systems.primitives import ConstantVectorSource

        zero = builder.AddSystem(ConstantVectorSource(np.zeros(plant.get_actuation_input_port().size())))
        builder.Connect(zero.get_output_port(0), plant.get_actuation_input_port())
    diagram = builder.Build()
    return diagram, plant


def _prefill_delay_lines(diagram, ctx, seg: IdentData, k: int) -> None:
    """Fill every torque delay line with the measured torque history before sample k."""
    from robust_drake.effects import TorqueDelayLine

    for sys in diagram.GetSystems():
        if isinstance(sys, TorqueDelayLine):
            sctx = sys.GetMyMutableContextFromRoot(ctx)
            x = sctx.get_mutable_discrete_state(0).get_mutable_value()
            t0 = float(seg.t[k])
            ts = t0 - sys.period * np.arange(sys.K)
            hist = np.column_stack([np.interp(ts, seg.t, seg.tau[:, j]) for j in range(sys.n)])
            x[0] = t0
            x[1:] = hist.ravel()


def _prefill_presliding(diagram, ctx, seg: IdentData, k: int) -> None:
    """Set every presliding (Dahl) block's state z to the value the measured positions before
    sample k imply (``effects.presliding_state`` along seg.q[:k+1]), as the delay lines get their
    torque history: left at 0 (or at the previous window's end) a 40 N m Dahl term starts each
    window with the wrong friction."""
    from robust_drake.effects import PreslidingFrictionBlock, presliding_state

    for sys in diagram.GetSystems():
        if isinstance(sys, PreslidingFrictionBlock):
            z = np.array([presliding_state(seg.q[:k + 1, j], sys.x0)[-1] if sys.active[j] else 0.0
                          for j in range(sys.n)])
            sys.GetMyMutableContextFromRoot(ctx).SetContinuousState(z)


def replay(robot, data: IdentData, coulomb, viscous, effects=(), inertias=None, horizon=DEFAULT_HORIZON,
           max_windows=MAX_WINDOWS, series: bool = False) -> dict:
    """Short-horizon replays; returns per-joint RMS position error [rad] (all samples, window ends).

    The windows' start samples depend only on ``data`` (its segments' lengths and dt),
    ``horizon`` and ``max_windows``, so two replays of the same data cover the same rows. With
    ``series`` the result also holds ``"error_q"`` (rows, n) [rad], the position error of every
    replayed row, and ``"window"`` (rows,), the window number of each row: the paired block test
    of two replays (``stages.replay_tests``) takes the windows as its blocks (each window starts
    from the measured state, so its error owes nothing to the window before; within a window the
    error is an integral and its rows are strongly dependent). These two entries are arrays and
    are not part of the report."""
    from pydrake.systems.analysis import Simulator

    from robust_drake.identification.consistency import set_plant_inertias

    errs, ends, win = [], [], []
    per_seg = max(1, max_windows // len(np.unique(data.segment)))
    for seg in data.segments():
        diagram, plant = build_replay_diagram(robot, seg, coulomb, viscous, effects, inertias)
        sim = Simulator(diagram)
        ctx = sim.get_mutable_context()
        pctx = plant.GetMyMutableContextFromRoot(ctx)
        for j in plant.GetJointIndices():  # the identified viscous level carries a URDF's joint damping
            joint = plant.get_joint(j)      # (least_squares.load_regressor): not counted twice
            if joint.num_velocities() and np.any(joint.GetDampingVector(pctx) != 0):
                joint.SetDampingVector(pctx, np.zeros(joint.num_velocities()))
        if inertias is not None:
            set_plant_inertias(plant, pctx, *inertias)
        sim.get_mutable_integrator().set_target_accuracy(1e-5)
        H = max(2, int(round(horizon / seg.dt)))
        starts = np.linspace(0, seg.N - H - 1, min(per_seg, max(1, (seg.N - 1) // H))).astype(int)
        for k in starts:
            ctx.SetTime(float(seg.t[k]))
            _prefill_delay_lines(diagram, ctx, seg, k)
            _prefill_presliding(diagram, ctx, seg, k)
            plant.SetPositions(pctx, seg.q[k])
            plant.SetVelocities(pctx, seg.qd[k])
            sim.Initialize()
            qs = []
            for m in range(k + 1, k + H + 1):
                sim.AdvanceTo(float(seg.t[m]))
                qs.append(plant.GetPositions(pctx).copy())
            e = np.array(qs) - seg.q[k + 1:k + H + 1]
            errs.append(e)
            ends.append(e[-1])
            win.append(np.full(len(e), len(ends) - 1))
    E = np.concatenate(errs)
    extra = {"error_q": E, "window": np.concatenate(win)} if series else {}
    return {
        "horizon_s": float(horizon), "windows": len(ends),
        "rms_q": [float(x) for x in np.sqrt(np.mean(E**2, axis=0))],
        "rms_q_end": [float(x) for x in np.sqrt(np.mean(np.array(ends) ** 2, axis=0))],
        "inertias": "identified (physically consistent)" if inertias is not None else "URDF nominal",
        **extra,
    }
