"""CPU time per simulated second (process time, so a busy machine disturbs it less): the SP1 closed loop at 2500 Hz against the same plant
simulated alone with a constant torque (same integrator, same step), in one run.

Prints both, their ratio, the real-time factor, and the cost of the discrete Python
parts (controller + observer + encoder + compensation) per tick, measured by difference.

    .venv/bin/python benchmarks/bench_closed_loop.py [--seconds 2] [--repeats 3]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from robust_drake.diagram import MAX_INTEGRATOR_STEP, ClosedLoopConfig, build_closed_loop
from robust_drake.models import add_arm


def plant_alone(seconds: float, period: float) -> float:
    builder = DiagramBuilder()
    plant, _ = add_arm(builder, "d2r2")
    src = builder.AddSystem(ConstantVectorSource(np.array([1.0, -0.5])))
    builder.Connect(src.get_output_port(0), plant.get_applied_generalized_force_input_port())
    diagram = builder.Build()
    sim = Simulator(diagram)
    steps = max(1, math.ceil(period / MAX_INTEGRATOR_STEP - 1e-9))
    ResetIntegratorFromFlags(sim, "runge_kutta2", period / steps)
    sim.Initialize()
    t0 = time.process_time()
    sim.AdvanceTo(seconds)
    return (time.process_time() - t0) / seconds


def closed_loop(seconds: float, **cfg) -> float:
    cl = build_closed_loop(ClosedLoopConfig(trajectory="sine", duration=seconds, **cfg))
    t0 = time.process_time()
    cl.simulate()
    return (time.process_time() - t0) / seconds


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    T = 1 / 2500
    rows = {
        "plant alone (constant torque)": lambda: plant_alone(a.seconds, T),
        "plant + friction (PD, exact v, no enc.)": lambda: closed_loop(a.seconds, controller="pd", observer="exact",
                                                                       encoder_resolution=None),
        "SP1 closed loop (full)": lambda: closed_loop(a.seconds, controller="sp1"),
        "SP1 closed loop + friction compensation": lambda: closed_loop(a.seconds, controller="sp1",
                                                                       friction_compensation=True),
    }
    best = {}
    for name, fn in rows.items():
        best[name] = min(fn() for _ in range(a.repeats))
    print(f"{'configuration':45s} {'cpu s / sim s':>15s} {'x real time':>12s} {'us / tick':>10s}")
    for name, w in best.items():
        print(f"{name:45s} {w:15.4f} {1 / w:12.1f} {w * 1e6 * T:10.1f}")
    p = best["plant alone (constant torque)"]
    full = best["SP1 closed loop (full)"]
    print(f"\nratio SP1 closed loop / plant alone: {full / p:.2f}")
    print(f"discrete parts + loggers + friction per tick: {(full - p) * 1e6 * T:.1f} us "
          f"(plant alone: {p * 1e6 * T:.1f} us per tick)")
    print(f"real-time factor of the full loop: {1 / full:.1f}x (aim >= 5x)")


if __name__ == "__main__":
    main()
