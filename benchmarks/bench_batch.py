"""Batch speed: the same 16 closed loops with 1 and with 2 workers, side by side.

Prints both wall times and their ratio (aim: >= 1.8x on 2 free cores), and the per-scenario
overhead of building the diagram, with and without reuse inside a worker.

    python benchmarks/bench_batch.py [--duration 1.0] [--workers 2]

The 1-worker run is in-process (what ``--workers 1`` does); the 2-worker run includes the
start-up of the worker pool, so the ratio is what a user sees.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402


def scenarios(duration):
    from robust_drake.scenario import expand_product

    # 4 controllers x 2 loads x 2 rates = 16 loops of different structure
    return expand_product({"robot": "d2r2", "trajectory": "cpt", "duration": duration,
                           "controllers": ["pd", "sp1", "sp2", "lgplus"],
                           "loads": ["none", "max"], "rates": [2500, 1000]})


def build_overhead(duration):
    """Build vs simulate time of one scenario, in this process, warm imports."""
    from robust_drake.diagram import build_closed_loop
    from robust_drake.scenario import Scenario

    s = Scenario(controller="sp1", duration=duration)
    build_closed_loop(s.to_config())._finish()  # warm-up (imports, first URDF parse)
    builds, sims = [], []
    for _ in range(3):
        t0 = time.perf_counter()
        loop = build_closed_loop(s.to_config())
        loop._finish()
        t1 = time.perf_counter()
        loop.simulate(duration)
        t2 = time.perf_counter()
        builds.append(t1 - t0)
        sims.append(t2 - t1)
    return float(np.median(builds)), float(np.median(sims))


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=4.0, help="simulated seconds per loop")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()

    from robust_drake.batch import clear_loop_cache, run_batch
    from robust_drake.montecarlo import draw_d2r2, montecarlo_scenarios

    sc = scenarios(args.duration)
    print(f"{len(sc)} scenarios, {args.duration:g} s simulated each, {os.cpu_count()} cores "
          f"(load average {os.getloadavg()[0]:.2f})")

    # Warm this process (imports, first URDF parse) so the 1-worker time is not inflated by
    # one-off start-up; the 2-worker time still includes starting its pool and fork server.
    from robust_drake.scenario import Scenario

    run_batch([Scenario(controller="pd", duration=0.05)], workers=1, progress=False)
    clear_loop_cache()
    t0 = time.perf_counter()
    serial = run_batch(sc, workers=1, progress=False)
    t_serial = time.perf_counter() - t0

    from robust_drake.parallel import run_parallel

    t0 = time.perf_counter()  # once per process: fork server start + preload of pydrake
    run_parallel(abs, [-1] * args.workers, workers=args.workers, progress=False)
    t_server = time.perf_counter() - t0

    t0 = time.perf_counter()
    par = run_batch(sc, workers=args.workers, progress=False)
    t_par = time.perf_counter() - t0

    assert set(serial["status"]) == {"ok"} and set(par["status"]) == {"ok"}, (
        serial[["name", "status", "error"]], par[["name", "status", "error"]])
    same = np.allclose(serial["maxerr_task"], par["maxerr_task"], rtol=1e-12, atol=0)
    print(f"1 worker  (in-process): {t_serial:7.2f} s")
    print(f"{args.workers} workers (processes): {t_par:7.2f} s   (includes starting the pool)")
    print(f"fork server start + pydrake preload (once per process): {t_server:.2f} s")
    print(f"speed-up: {t_serial / t_par:.2f}x  ({t_serial / (t_par + t_server):.2f}x counting the "
          f"fork server start; aim >= 1.8x on 2 free cores)   identical metrics: {same}")
    print(f"sum of per-scenario wall times: 1 worker {serial['wall_seconds'].sum():.2f} s, "
          f"{args.workers} workers {par['wall_seconds'].sum():.2f} s")
    cpu1, cpu2 = serial["cpu_seconds"].sum(), par["cpu_seconds"].sum()
    print(f"sum of per-scenario CPU times: 1 worker {cpu1:.2f} s, {args.workers} workers "
          f"{cpu2:.2f} s (ratio {cpu2 / cpu1:.2f}: work per scenario is the same in workers)")
    t0 = time.perf_counter()
    run_parallel(abs, [-1] * args.workers, workers=args.workers, progress=False)
    t_pool = time.perf_counter() - t0
    print(f"pool start-up + shutdown (trivial items, fork server already running): "
          f"{t_pool:.3f} s")
    if os.getloadavg()[0] > 1.5:
        print("NOTE: the machine is busy (load average above): the wall-time ratio is not a "
              "measure of the code; rerun on an idle machine")

    b, s = build_overhead(args.duration)
    print(f"diagram build: {1e3 * b:.1f} ms per scenario vs {1e3 * s:.0f} ms simulation "
          f"({100 * b / (b + s):.1f} % of a {args.duration:g} s run)")
    print(f"build share in the 1-worker batch: {serial['build_seconds'].sum():.2f} s of "
          f"{serial['wall_seconds'].sum():.2f} s")

    # Reuse: 8 Monte Carlo draws of one controller share one diagram per worker.
    thetas, _ = draw_d2r2(8, seed=0)
    mc = montecarlo_scenarios("d2r2", ["sp1"], thetas, base={"duration": args.duration})
    clear_loop_cache()
    reused = run_batch(mc, workers=1, progress=False, reuse=True)
    clear_loop_cache()
    fresh = run_batch(mc, workers=1, progress=False, reuse=False)
    print(f"8 draws, one structure: builds {int((reused['build_seconds'] > 0).sum())} "
          f"(reuse) vs {int((fresh['build_seconds'] > 0).sum())} (no reuse); build time "
          f"{reused['build_seconds'].sum():.3f} s vs {fresh['build_seconds'].sum():.3f} s; "
          f"wall {reused['wall_seconds'].sum():.2f} s vs {fresh['wall_seconds'].sum():.2f} s; "
          f"identical metrics: "
          f"{np.allclose(reused['maxerr_task'], fresh['maxerr_task'], rtol=1e-12, atol=0)}")


if __name__ == "__main__":
    main()
