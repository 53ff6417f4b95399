"""Issue 26's table in one run: the per-tick regressor, the loops, and the repair at the length of real logs.

1. Slotine-Li regressor Y(q, qd, v, a) of the Panda and serial7, one state (the controllers' path,
   ``InverseDynamicsRegressor.slotine_li_single``: Pinocchio) against one Drake inverse dynamics in the
   same process (SetPositions, SetVelocities, CalcForceElementsContribution, CalcInverseDynamics: what
   one tau for a new state costs; the bare CalcInverseDynamics call beside it), and the numpy reference
   route it replaced.  Interleaved rounds; the fastest round and the median, microseconds per call.
2. Loop / plant-alone CPU ratios (``bench_closed_loop.py``'s rows): the D2R2 SP1 loop at 2500 Hz and the
   Panda SP1 loop at 1 kHz and 2500 Hz, with the real-time factor.
3. Repair of serial7 dead-zone logs (``bench_repair.py``, each in its own process so its peak RSS is its
   own): CPU seconds, wall seconds and peak RSS at 20 s and 100 s of 1 kHz logs (19.5k / 99.5k rows x 7
   joints, fit and validation each).
4. The confidence ellipsoid: the chordal SDP through Drake's MathematicalProgram (bundled Clarabel, qdldl) and
   the same data handed to pip clarabel with qdldl and with faer, CPU seconds side by side; the closed-form
   energy bound at 1000 samples.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_speed.py [--seconds 2] [--repeats 5]
        [--repair 20,100] [--repair-dir DIR] [--ellipsoid 30,100] [--energy-samples 1000]
        [--skip regressor,loops,repair,ellipsoid]

Timings on a shared machine are upper bounds; the ratios (measured side by side in one process) are what
to quote.  The D2R2 loop in instructions (load-independent): ``benchmarks/instructions_per_tick.sh``.
Print only, not a test.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import re
import statistics
import subprocess
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import numpy as np  # noqa: E402


def _rounds(fns: dict, calls: int, repeats: int) -> dict:
    """{name: (fastest, median)} microseconds per call over ``repeats`` interleaved rounds."""
    out = {k: [] for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            t = time.perf_counter()
            for _ in range(calls):
                f()
            out[k].append((time.perf_counter() - t) / calls * 1e6)
    return {k: (min(v), statistics.median(v)) for k, v in out.items()}


def regressor_table(repeats: int) -> None:
    from pydrake.multibody.tree import MultibodyForces

    from robust_drake.regressor import InverseDynamicsRegressor

    print("\n1. Slotine-Li regressor, one state, against Drake inverse dynamics in the same process "
          "(us per call: fastest round / median)")
    print(f"{'robot':10s} {'n':>2s} {'p':>3s} {'Drake ID (set state + forces + ID)':>36s} {'bare ID':>14s} "
          f"{'Slotine-Li (Pinocchio)':>24s} {'numpy reference':>18s} {'SL / ID':>8s} {'SL / bare':>9s}")
    rng = np.random.default_rng(0)
    for robot in ("panda", "serial7"):
        reg = InverseDynamicsRegressor.from_robot(robot)
        plant = reg.plant
        ctx = plant.CreateDefaultContext()
        forces = MultibodyForces(plant)
        q, qd, v, a = rng.normal(size=(4, reg.n))

        def drake_id():
            plant.SetPositions(ctx, q)
            plant.SetVelocities(ctx, qd)
            plant.CalcForceElementsContribution(ctx, forces)
            plant.CalcInverseDynamics(ctx, a, forces)

        fns = {"id": drake_id, "bare": lambda: plant.CalcInverseDynamics(ctx, a, forces),
               "sl": lambda: reg.slotine_li_single(q, qd, v, a)}
        r = _rounds(fns, 2000, repeats)
        ref = _rounds({"ref": lambda: reg.slotine_li_single_reference(q, qd, v, a)}, 50, max(3, repeats // 2))["ref"]
        f = lambda k: f"{r[k][0]:6.1f} / {r[k][1]:6.1f}"  # noqa: E731
        print(f"{robot:10s} {reg.n:2d} {reg.p_base:3d} {f('id'):>36s} {f('bare'):>14s} {f('sl'):>24s} "
              f"{ref[0]:7.1f} / {ref[1]:6.1f} {r['sl'][0] / r['id'][0]:8.2f} {r['sl'][0] / r['bare'][0]:9.2f}")
    print("   aim (issue 26): Slotine-Li on the Panda <= 2x one Drake inverse dynamics")


def loop_table(seconds: float, repeats: int) -> None:
    import bench_closed_loop as bcl

    print(f"\n2. Loop / plant alone, CPU per simulated second, {repeats} interleaved rounds of {seconds:g} s")
    print(f"{'loop':34s} {'rate Hz':>8s} {'plant us/tick':>14s} {'loop us/tick':>13s} {'x plant (median)':>17s} "
          f"{'x plant (fastest)':>18s} {'x real time':>12s}")
    cases = []
    T, rows = bcl.d2r2_rows(seconds)
    cases.append(("D2R2 SP1 (full loop)", T, {"plant": rows["plant alone (constant torque)"],
                                              "loop": rows["+ loggers (= full loop)"]}))
    for rate in (1000.0, 2500.0):
        T, rows = bcl.panda_rows(seconds, rate)
        cases.append(("Panda SP1 (full loop)", T, {"plant": rows["panda plant alone (constant torque)"],
                                                   "loop": rows["panda SP1 loop (full)"]}))
    for name, T, rows in cases:
        med, low = bcl.measure(rows, repeats)
        print(f"{name:34s} {1 / T:8g} {med['plant'] * T * 1e6:14.1f} {med['loop'] * T * 1e6:13.1f} "
              f"{med['loop'] / med['plant']:17.2f} {low['loop'] / low['plant']:18.2f} {1 / med['loop']:12.2f}")
    print("   aims: D2R2 <= 2.5x the plant; Panda <= 3x the plant, >= 2x real time at 2500 Hz (one quiet core)")


def repair_table(durations: list[float], folder: str) -> None:
    print("\n3. Repair of serial7 dead-zone logs (1 kHz, fit and validation each), one process per size")
    print(f"{'log':>8s} {'rows x joints':>14s} {'cpu s':>8s} {'wall s':>8s} {'peak RSS MB':>12s}   stages (cpu s)")
    for d in durations:
        sub = os.path.join(folder, f"serial7_{d:g}s")
        os.makedirs(sub, exist_ok=True)
        cmd = [sys.executable, str(HERE / "bench_repair.py"), "--duration", str(d), "--keep", sub, "--reuse"]
        out = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(HERE.parent)))
        text = out.stdout
        m = re.search(r"repair: (\d+) fit samples x (\d+) joints", text)
        w = re.search(r"wall ([\d.]+) s\s+cpu ([\d.]+) s\s+peak RSS (\d+) MB", text)
        if out.returncode or not (m and w):
            print(f"{d:7g}s  FAILED (exit {out.returncode}): {(out.stderr or text).strip().splitlines()[-1:]}")
            continue
        stages = re.findall(r"^\s+(\w+)\s+[\d.]+\s+[\d.]+\s+([\d.]+)", text, flags=re.M)
        st = ", ".join(f"{k} {float(c):.1f}" for k, c in stages if float(c) >= 0.5)
        print(f"{d:7g}s {m.group(1) + ' x ' + m.group(2):>14s} {float(w.group(2)):8.1f} {float(w.group(1)):8.1f} "
              f"{int(w.group(3)):12d}   {st}")
    print("   aims: 10^5 rows x 7 joints < 60 s CPU and < 2 GB peak; the 20k case no slower than before")


def ellipsoid_table(counts: list[int], energy_samples: int) -> None:
    """The chordal SDP (CI section 3.1) posed in Drake's MathematicalProgram and solved by Drake's bundled
    Clarabel, against the same data handed to the pip clarabel package (faer), same process; CPU seconds
    of the solve (the pip build may use 2 threads) and the trace; the closed-form energy bound beside it."""
    from robust_drake.experiments.calafiore import simulate_identification
    from robust_drake.regressor import imi_scara_regressor
    from robust_drake.uncertainty.ellipsoid import solve_ellipsoid
    from robust_drake.uncertainty.regression import CI_BOUNDS, build_uncertainty_model

    print("\n4. Confidence ellipsoid (IMI SCARA, CI bounds), chordal SDP: Drake MathematicalProgram + bundled "
          "Clarabel (qdldl; Drake 1.51 refuses the option direct_solve_method) vs pip clarabel directly with the "
          "same qdldl and with faer (CPU s of solve_ellipsoid: build, solve, 200-draw certificate / trace)")
    print(f"{'samples':>8s} {'drake/clarabel':>22s} {'direct qdldl':>22s} {'direct faer':>22s} "
          f"{'drake/qdldl':>11s} {'drake/faer':>10s}")

    def model_of(n):
        d = simulate_identification(n, seed=0)
        return build_uncertainty_model(imi_scara_regressor, d["q"], d["qd"], d["qdd"], d["tau"], CI_BOUNDS)

    method = os.environ.get("RD_CLARABEL_METHOD")
    for n in counts:
        model, row = model_of(n), {}
        for key, backend, kkt in (("drake", "drake", None), ("qdldl", "direct", "qdldl"), ("faer", "direct", "faer")):
            if kkt:
                os.environ["RD_CLARABEL_METHOD"] = kkt  # the direct backend's linear solver
            c = time.process_time()
            r = solve_ellipsoid(model, formulation="chordal", backend=backend, certify_draws=200)
            row[key] = (time.process_time() - c, r.trace)
        (cd, td), (cq, tq), (cf, tf) = row["drake"], row["qdldl"], row["faer"]
        print(f"{n:8d} {cd:12.1f} / {td:8.3f} {cq:12.1f} / {tq:8.3f} {cf:12.1f} / {tf:8.3f} {cd / cq:11.2f} "
              f"{cd / cf:10.2f}")
    if method is None:
        os.environ.pop("RD_CLARABEL_METHOD", None)
    else:
        os.environ["RD_CLARABEL_METHOD"] = method
    if energy_samples:
        model = model_of(energy_samples)
        c = time.process_time()
        r = solve_ellipsoid(model, formulation="energy", certify_draws=200)
        print(f"{energy_samples:8d} energy bound (closed form, no SDP): {time.process_time() - c:.1f} s CPU, trace "
              f"{r.trace:.3f} (BUILD_NOTES: 2.2-4x the SDP's)")
    print("   aims: Drake no slower than the solver called directly (at equal KKT solver: drake/qdldl); "
          "1000 samples SDP-tight < 30 s")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per loop run")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--repair", default="20,100", help="log durations [s] of the repair rows ('' = none)")
    ap.add_argument("--repair-dir", default=None, help="folder for the repair logs (kept and reused between runs)")
    ap.add_argument("--ellipsoid", default="30,100", help="sample counts of the chordal SDP rows ('' = none)")
    ap.add_argument("--energy-samples", type=int, default=1000, help="samples of the energy-bound row (0 = none)")
    ap.add_argument("--skip", default="", help="comma list of parts to skip: regressor, loops, repair, ellipsoid")
    a = ap.parse_args()
    skip = {s for s in a.skip.split(",") if s}
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}; cpu count {os.cpu_count()}; "
          f"load average {os.getloadavg()[0]:.1f}")
    if "regressor" not in skip:
        regressor_table(max(a.repeats, 5))
    if "loops" not in skip:
        loop_table(a.seconds, a.repeats)
    if "repair" not in skip and a.repair:
        import tempfile

        folder = a.repair_dir or tempfile.mkdtemp(prefix="bench_speed_")
        repair_table([float(x) for x in a.repair.split(",")], folder)
    if "ellipsoid" not in skip and (a.ellipsoid or a.energy_samples):
        ellipsoid_table([int(x) for x in a.ellipsoid.split(",") if x], a.energy_samples)


if __name__ == "__main__":
    main()
