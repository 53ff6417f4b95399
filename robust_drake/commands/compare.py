"""``robust-drake compare``: rerun the Jaritz & Spong comparison (tables 2-7) on the simulated D2R2.

``robust-drake compare --table 4`` runs SP1, SP2, ZC and LG+ on the CPT with friction
compensation and no load, in parallel, and prints JS table 4's layout with the published value
beside each simulated one. ``--json`` prints a list of rows (keys ``controller``, ``load``,
``friction_compensation``, ``error1, maxerr1, error2, maxerr2, error_task, maxerr_task``, ...);
``--plot DIR`` writes the figure analogs (tracking errors and torques per controller).
"""

from __future__ import annotations

import sys

from robust_drake.cli import add_output_flags, print_json


def register(sub):
    p = sub.add_parser("compare", help="rerun Jaritz & Spong tables 2-7 (SP1, SP2, ZC, LG+) beside the published values")
    p.add_argument("--table", required=True, nargs="+",
                   help="table number(s) 2-7, or 'all' (2, 3: CPT; 4, 5: CPT + friction compensation; 6, 7: circle)")
    p.add_argument("--controllers", default="sp1,sp2,zc,lgplus",
                   help="comma-separated controllers (default: the paper's sp1,sp2,zc,lgplus)")
    p.add_argument("--observer", default="averaging",
                   help="velocity estimator (default: averaging, JS eqs. 64/66; also euler, filtered, averaging67, kalman, nonlinear)")
    p.add_argument("--rate", type=float, default=2500.0, help="sample rate [Hz] (paper: 2500)")
    p.add_argument("--duration", type=float, default=None, help="shorten every run [s] (tests, quick looks)")
    p.add_argument("--rigid", action="store_true", help="rigid arm (the default; with --flexible: both, side by side)")
    p.add_argument("--flexible", action="store_true",
                   help="flexible D2R2: two-mass drives, motor-side encoders, link-2 bending (BUILD_NOTES 'Flexible D2R2')")
    p.add_argument("--viscous-compensation", action="store_true",
                   help="add F_v_hat v to the fixed Coulomb compensation (JS section 7.1; tables 4-7)")
    p.add_argument("--workers", type=int, default=None, help="parallel runs (default: the core count)")
    add_output_flags(p, plot="DIR")
    p.set_defaults(func=run)


def _tables(values) -> list[int]:
    from robust_drake.experiments.jaritz_spong import TABLES, _check_table

    if any(str(v).lower() == "all" for v in values):
        return sorted(TABLES)
    return [_check_table(v) for v in values]


def run(args) -> int:
    from robust_drake.errors import RobustDrakeError
    from robust_drake.experiments import jaritz_spong as js
    from robust_drake.registry import names

    if args.plot is not None and not args.plot.strip():
        raise RobustDrakeError("--plot is empty; give a file or folder path")
    tables = _tables(args.table)
    controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    known = names("controller")
    bad = [c for c in controllers if c not in known]
    if bad or not controllers:
        raise RobustDrakeError(f"unknown controller(s) {bad}; known: {', '.join(known)}")
    if args.observer not in names("observer"):
        raise RobustDrakeError(f"unknown observer {args.observer!r}; known: {', '.join(names('observer'))}")
    if args.duration is not None and not args.duration > 0:
        raise RobustDrakeError(f"--duration must be positive (got {args.duration})")
    models = [m for m, on in (("rigid", args.rigid), ("flexible", args.flexible)) if on] or ["rigid"]
    specs = [js.run_spec(t, c, duration=args.duration, rate=args.rate, observer=args.observer,
                         logs=bool(args.plot), model=m, viscous_compensation=args.viscous_compensation)
             for t in tables for c in controllers for m in models]
    rows = js.run_specs(specs, workers=args.workers, progress=not args.json, desc="compare")
    plots = []
    if args.plot:
        for t in tables:
            for m in models:
                trows = [r for r in rows if r["table"] == t and "logs" in r and r.get("model", "rigid") == m]
                if trows:
                    out = args.plot if m == "rigid" else str(__import__("pathlib").Path(args.plot) / m)
                    plots.append(str(js.plot_table(t, trows, out)))
        plots.append(str(js.plot_friction_curve(__import__("pathlib").Path(args.plot) / "fig3_friction.png")))
    for r in rows:
        r.pop("logs", None)
    failed = [r for r in rows if "error" in r]
    if args.json:
        print_json(rows)
    else:
        for t in tables:
            print(js.format_paper_table(t, [r for r in rows if r["table"] == t]))
            print()
        if plots:
            print("figures: " + ", ".join(plots))
    for r in failed:
        print(f"run failed: table {r['table']} {r['controller']}: {r['error']}", file=sys.stderr)
    return 1 if failed else 0
