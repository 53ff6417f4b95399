"""CPU time per simulated second of the closed loop, block by block (issue 14, "Speed of the 2500 Hz loop").

Process time (so a busy machine disturbs it less), every configuration run in turn in one process,
``--repeats`` rounds, median per configuration; the ratios to the plant alone are what to quote.

Part 1, the 2-link D2R2 SP1 loop at 2500 Hz (one RK2 step per tick), built up one block at a time:

    plant alone (constant torque)
    + plant friction (constant torque)
    + reference and SP1 controller (exact q, v, v_error from the plant state, C++ selectors)
    + encoder (quantiser)
    + velocity estimator (averaging, JS eqs. 64/66)
    + saturation
    + loggers                               = the full loop of ``build_closed_loop``

each row in us per tick, x plant alone, and the increment over the row above; then the full loop
with the Python reference blocks (reference, encoder, friction, estimator as the Python LeafSystems
they replace; the controller as above) for comparison.

Part 2, a 7-axis SP1 loop at 1 kHz (the Panda with Gaz et al.'s sigmoid friction, a 20-bit encoder
and Franka's torque limits, as tests/test_anyarm_controllers.py; three RK2 steps per tick): plant alone
and the full loop, real-time factor.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_closed_loop.py [--seconds 2] [--repeats 5]

Each table is printed twice: the median of the rounds and the fastest round (on a shared machine the
fastest round is the least disturbed). ``benchmarks/instructions_per_tick.sh`` counts the same rows
in instructions (valgrind), a figure no other load on the machine changes.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Adder, ConstantVectorSource, Demultiplexer, MatrixGain, Multiplexer

from robust_drake.diagram import MAX_INTEGRATOR_STEP, ClosedLoop, ClosedLoopConfig
from robust_drake.models import add_arm
from robust_drake.systems.friction import CoulombViscousFriction, D2R2_COULOMB, D2R2_VISCOUS
from robust_drake.systems.sensors import QuantizingEncoder
from robust_drake.trajectories import ReferenceTrajectory

PANDA_READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
PANDA_LIMITS = [87.0] * 4 + [12.0] * 3


def _rk2(sim, period):
    steps = max(1, math.ceil(period / MAX_INTEGRATOR_STEP - 1e-9))
    ResetIntegratorFromFlags(sim, "runge_kutta2", period / steps)


def plant_alone(robot, period, seconds, friction=None, q0=None):
    """The plant under a constant torque (plus the closed loop's friction block if given)."""
    builder = DiagramBuilder()
    plant, _ = add_arm(builder, robot)
    n = plant.num_velocities()
    src = builder.AddSystem(ConstantVectorSource(np.linspace(1.0, -0.5, n)))
    if friction is None:
        builder.Connect(src.get_output_port(0), plant.get_applied_generalized_force_input_port())
    else:
        fr = builder.AddSystem(ClosedLoop.friction_block(n, *friction))
        add = builder.AddSystem(Adder(2, n))
        builder.Connect(plant.get_state_output_port(), fr.GetInputPort("state"))
        builder.Connect(src.get_output_port(0), add.get_input_port(0))
        builder.Connect(fr.GetOutputPort("generalized_force"), add.get_input_port(1))
        builder.Connect(add.get_output_port(0), plant.get_applied_generalized_force_input_port())
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    if q0 is not None:
        plant.SetPositions(plant.GetMyMutableContextFromRoot(ctx), q0)
    sim = Simulator(diagram, ctx)
    _rk2(sim, period)
    sim.Initialize()
    t0 = time.process_time()
    sim.AdvanceTo(seconds)
    return (time.process_time() - t0) / seconds


# ------------------------------------------------------------------ stand-ins for blocks not yet added
class ExactPosition(Diagram):
    """q = state[:n] (a C++ MatrixGain): the loop without an encoder."""

    def __init__(self, n, theta_m=None):
        super().__init__()
        b = DiagramBuilder()
        g = b.AddSystem(MatrixGain(np.eye(n, 2 * n)))
        b.ExportInput(g.get_input_port(0), "state")
        b.ExportOutput(g.get_output_port(0), "q")
        b.BuildInto(self)


def exact_velocity(ctx):
    """v = state[n:], v_error = v - qd_d in C++ (MatrixGain): the loop without a velocity estimator."""
    n = ctx.n
    d = Diagram()
    b = DiagramBuilder()
    mux = b.AddSystem(Multiplexer([2 * n, 3 * n, n]))
    G = np.zeros((2 * n, 6 * n))
    G[:n, n:2 * n] = np.eye(n)
    G[n:, n:2 * n], G[n:, 3 * n:4 * n] = np.eye(n), -np.eye(n)
    g = b.AddSystem(MatrixGain(G))
    demux = b.AddSystem(Demultiplexer([n, n]))
    b.Connect(mux.get_output_port(0), g.get_input_port(0))
    b.Connect(g.get_output_port(0), demux.get_input_port(0))
    for i, name in enumerate(("state", "x_d", "q")):
        b.ExportInput(mux.get_input_port(i), name)
    b.ExportOutput(demux.get_output_port(0), "v")
    b.ExportOutput(demux.get_output_port(1), "v_error")
    b.BuildInto(d)
    return d


class NoLogs(ClosedLoop):
    def _add_logs(self, x_d, u, tau, obs):
        self._log, self.extra_logs = None, {}


class NoLogsExactQ(NoLogs):
    encoder_block = ExactPosition


class PythonBlocks(ClosedLoop):
    """The full loop with the Python reference blocks (the design before issue 14's speed work)."""

    reference_block = ReferenceTrajectory
    encoder_block = QuantizingEncoder
    friction_block = CoulombViscousFriction


def advance(cl: ClosedLoop, seconds: float) -> float:
    """What ``ClosedLoop.simulate`` does up to the integration (start at rest at q_d(0)); CPU s per sim s."""
    cl._finish()
    ctx = cl.diagram.CreateDefaultContext()
    q0, qd0 = cl.reference.initial_state()
    cl.plant.SetPositions(cl.plant.GetMyMutableContextFromRoot(ctx), q0)
    if hasattr(cl.observer, "set_initial"):
        cl.observer.set_initial(cl.observer.GetMyMutableContextFromRoot(ctx), q0, q0, qd0)
    cl.reference_source.tabulate(seconds)
    sim = Simulator(cl.diagram, ctx)
    _rk2(sim, cl.period)
    sim.Initialize()
    t0 = time.process_time()
    sim.AdvanceTo(seconds)
    return (time.process_time() - t0) / seconds


def d2r2_rows(seconds):
    base = dict(robot="d2r2", controller="sp1", trajectory="sine", duration=seconds)
    fr = (D2R2_COULOMB, D2R2_VISCOUS)
    T = 1 / 2500
    return T, {
        "plant alone (constant torque)": lambda: plant_alone("d2r2", T, seconds),
        "+ plant friction": lambda: plant_alone("d2r2", T, seconds, friction=fr),
        "+ reference + SP1 controller (exact q, v)": lambda: advance(NoLogsExactQ(ClosedLoopConfig(
            observer=exact_velocity, torque_limit=None, **base)), seconds),
        "+ encoder (quantiser)": lambda: advance(NoLogs(ClosedLoopConfig(
            observer=exact_velocity, torque_limit=None, **base)), seconds),
        "+ velocity estimator (averaging)": lambda: advance(NoLogs(ClosedLoopConfig(torque_limit=None, **base)),
                                                            seconds),
        "+ saturation": lambda: advance(NoLogs(ClosedLoopConfig(**base)), seconds),
        "+ loggers (= full loop)": lambda: advance(ClosedLoop(ClosedLoopConfig(**base)), seconds),
        "full loop, Python reference/encoder/friction/estimator": lambda: advance(PythonBlocks(ClosedLoopConfig(
            observer_params={"python": True}, **base)), seconds),
    }


def panda_rows(seconds, rate=1000.0):
    from robust_drake.models import make_plant

    plant = make_plant("panda")
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, PANDA_READY)
    K = (50.0 * np.diag(plant.CalcMassMatrix(ctx))).tolist()
    cfg = dict(robot="panda", trajectory="step", rate=rate, duration=seconds, controller="sp1",
               controller_params={"epsilon": 1.0, "K": K, "Lambda": 20.0},
               trajectory_params={"amplitude": 0.3, "omega": 8.0, "offset": PANDA_READY, "duration": seconds},
               encoder_resolution=2 * np.pi / 2 ** 20, torque_limit=PANDA_LIMITS, effects=[("sigmoid_friction", {})])
    T = 1 / rate
    return T, {
        "panda plant alone (constant torque)": lambda: plant_alone("panda", T, seconds, q0=PANDA_READY),
        "panda SP1 loop (full)": lambda: advance(ClosedLoop(ClosedLoopConfig(**cfg)), seconds),
    }


def measure(rows, repeats):
    """(median, min) per row over ``repeats`` rounds, each round running every row once in turn.
    The min is the least disturbed run (a shared machine only ever adds time)."""
    times = {k: [] for k in rows}
    for _ in range(repeats):
        for name, fn in rows.items():
            times[name].append(fn())
    return {k: statistics.median(v) for k, v in times.items()}, {k: min(v) for k, v in times.items()}


def print_table(title, T, med, base_key):
    p = med[base_key]
    print(f"\n{title} ({1 / T:g} Hz)")
    print(f"{'configuration':48s} {'us/tick':>8s} {'x plant':>8s} {'+us/tick':>9s} {'x real time':>12s}")
    prev = None
    for name, w in med.items():
        inc = "" if prev is None or not name.startswith("+") else f"{(w - prev) * T * 1e6:9.1f}"
        print(f"{name:48s} {w * T * 1e6:8.1f} {w / p:8.2f} {inc:>9s} {1 / w:12.1f}")
        prev = w


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--part", choices=("all", "d2r2", "panda"), default="all")
    ap.add_argument("--row", type=int, default=None,
                    help="run only row ROW of --part once (for instructions_per_tick.sh) and exit")
    a = ap.parse_args()
    if a.row is not None:
        _, rows = (d2r2_rows if a.part == "d2r2" else panda_rows)(a.seconds)
        name = list(rows)[a.row]
        print(name)
        rows[name]()
        return
    if a.part in ("all", "d2r2"):
        T, rows = d2r2_rows(a.seconds)
        med, low = measure(rows, a.repeats)
        base, full = "plant alone (constant torque)", "+ loggers (= full loop)"
        print_table("D2R2 SP1 loop, block by block, median of the rounds", T, med, base)
        print_table("the same, fastest round", T, low, base)
        print(f"ratio full loop / plant alone: {med[full] / med[base]:.2f} (medians), "
              f"{low[full] / low[base]:.2f} (fastest rounds); aim <= 3.5")
    if a.part in ("all", "panda"):
        T, rows = panda_rows(a.seconds)
        med, low = measure(rows, a.repeats)
        print_table("Panda (7 joints) SP1 loop, median of the rounds", T, med, "panda plant alone (constant torque)")
        print(f"real-time factor of the 7-axis loop: {1 / med['panda SP1 loop (full)']:.2f}x median, "
              f"{1 / low['panda SP1 loop (full)']:.2f}x fastest (aim >= 2)")


if __name__ == "__main__":
    main()
