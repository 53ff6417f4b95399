"""Repair speed: 20k fit + 20k validation samples of a 7-joint arm repaired, with plots.

Builds the case of issue 13 (``outside_case("dead_zone", robot="serial7", duration=20,
rate_hz=1000)``: serial7 with a driver dead-zone on joint 1, 1 kHz, 20 s each for fit and
validation), then runs the whole repair (``run_repair``, as ``robust-drake repair ... --out``
does) and prints the wall time, the CPU time, the peak RSS and the time of each stage:

    load, baseline, estimator, selection, guard, replay, nominal, plots, sweep, other

(``sweep``: the estimator's cut-off sweep, which runs with plots on when the Hausman test is
significant; ``other``: writing report.md/json and what the stages do not cover).

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_repair.py [--duration 20] [--rate 1000] [--no-plots]
        [--case dead_zone] [--robot serial7] [--keep DIR] [--default-allocator]

The same figure from the command line (what BUILD_NOTES quotes):
``/usr/bin/time -v robust-drake repair dead_zone_fit.csv --robot serial7 --validate
dead_zone_validate.csv --out rep -q``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import resource
import sys
import tempfile
import time
from collections import defaultdict

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

#: stage name -> (module, function) timed by wrapping the module attribute the pipeline calls
STAGES = {
    "load": [("stages", "load_inputs")],
    "baseline": [("stages", "fit_baseline")],
    "estimator": [("stages", "choose_estimator")],
    "selection": [("stages", "select_effects"), ("stages", "resolve_torque_scale")],
    "guard": [("stages", "never_worse")],
    "replay": [("stages", "replay_guard")],
    "nominal": [("stages", "compare_nominal")],
    "plots": [("report", "write_plots"), ("instruments", "plot_cutoff_sweep")],
    "sweep": [("instruments", "cutoff_sweep")],
}


def _vm_hwm_mb() -> float | None:
    """Peak RSS of this process since the last :func:`_reset_hwm` [MB] (Linux /proc), else None."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def _reset_hwm() -> None:
    try:  # "5" resets the peak RSS (VmHWM) to the current RSS (Linux >= 4.0)
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _timed(fn, name, times, peaks):
    def wrapper(*a, **k):
        _reset_hwm()
        t, c = time.perf_counter(), time.process_time()
        try:
            return fn(*a, **k)
        finally:
            times[name] += time.perf_counter() - t
            times[name + ":cpu"] += time.process_time() - c
            hwm = _vm_hwm_mb()
            if hwm is not None:
                peaks[name] = max(peaks.get(name, 0.0), hwm)
    return wrapper


def instrument(times, peaks):
    """Wrap the stage functions (looked up as module attributes by run_repair) with timers."""
    from robust_drake.identification import instruments
    from robust_drake.model_repair import report, stages

    mods = {"stages": stages, "report": report, "instruments": instruments}
    for name, fns in STAGES.items():
        for mod, fn in fns:
            setattr(mods[mod], fn, _timed(getattr(mods[mod], fn), name, times, peaks))


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="dead_zone")
    ap.add_argument("--robot", default="serial7")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--keep", help="folder for the CSVs and the report (default: a temporary one)")
    ap.add_argument("--reuse", action="store_true",
                    help="with --keep: reuse <case>_fit.csv / <case>_validate.csv already there (not re-simulated)")
    ap.add_argument("--default-allocator", action="store_true",
                    help="leave glibc's allocator as it is (the command line keeps freed memory: allocator.py)")
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair
    from robust_drake.synthetic.simulated_cases import outside_case

    folder = args.keep or tempfile.mkdtemp(prefix="bench_repair_")
    t = time.perf_counter()
    fit_csv, val_csv = (os.path.join(folder, f"{args.case}_{r}.csv") for r in ("fit", "validate"))
    if args.reuse and args.keep and os.path.exists(fit_csv) and os.path.exists(val_csv):
        print(f"case {args.case} on {args.robot}: reusing {fit_csv} and {val_csv}")
    else:
        fit_csv, val_csv, truth = outside_case(args.case, robot=args.robot, duration=args.duration,
                                               rate_hz=args.rate, out_dir=folder)
        print(f"case {args.case} on {args.robot}: {args.duration:g} s at {args.rate:g} Hz, fit and validate "
              f"({time.perf_counter() - t:.1f} s to simulate; not counted)")
    if not args.default_allocator:
        from robust_drake.allocator import reuse_freed_memory

        reuse_freed_memory()  # what `robust-drake repair` does
    rss_before = peak_rss_mb()
    times, peaks = defaultdict(float), {}
    instrument(times, peaks)
    opts = RepairOptions(robot=args.robot, plots=not args.no_plots)
    t, c = time.perf_counter(), time.process_time()
    rep = run_repair([fit_csv], opts, validate_paths=[val_csv], out_dir=os.path.join(folder, "rep"),
                     progress=lambda msg: None)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    print(f"repair: {rep['samples']} fit samples x {len(rep['joint_names'])} joints, verdict {rep['verdict']}, "
          f"effects {[(e['kind'], e['joint']) for e in rep['effects']]}")
    print(f"wall {wall:.1f} s   cpu {cpu:.1f} s   peak RSS {max([peak_rss_mb(), *peaks.values()]):.0f} MB ("
          f"{rss_before:.0f} MB after simulating the case)")
    times["other"] = wall - sum(times[k] for k in STAGES)
    times["other:cpu"] = cpu - sum(times[k + ":cpu"] for k in STAGES)
    print("  stage        wall s      %    cpu s   peak RSS in the stage [MB]")
    for name in list(STAGES) + ["other"]:
        peak = f"{peaks[name]:8.0f}" if name in peaks else "       -"
        print(f"  {name:10s} {times[name]:8.1f} {100 * times[name] / wall:6.1f} {times[name + ':cpu']:8.1f} {peak}")


if __name__ == "__main__":
    main()
