"""``robust-drake epsilon-search``: the Jaritz & Spong boundary-layer tuning (section 9, table 1).

For each controller, the smallest epsilon (a grid of factors times the table-1 value) without
sustained vibration, vibration being a measured quantity: the fraction of the applied torque's
power above ``--f-cut`` Hz (default 50) exceeding ``--threshold`` (default 0.01) on any joint
(``robust_drake.experiments.epsilon_search``). Prints the found epsilon beside table 1's, per arm
model (``--rigid`` / ``--flexible``; both side by side when both are given).
"""

from __future__ import annotations

from robust_drake.cli import add_output_flags, format_table, print_json


def register(sub):
    p = sub.add_parser("epsilon-search",
                       help="JS table 1: smallest boundary layer epsilon without sustained torque vibration",
                       description="For each robust controller, simulate the CPT (JS table 2 setting) over a grid of "
                                   "epsilon values (factors of the published table 1 value) and report the smallest "
                                   "epsilon without sustained vibration, defined as more than --threshold of the "
                                   "applied torque's power above --f-cut Hz, beside table 1.")
    p.add_argument("--controllers", default="sp1,sp2,zc,lgplus", help="comma-separated (default sp1,sp2,zc,lgplus)")
    p.add_argument("--factors", default=None,
                   help="comma-separated epsilon / table-1 factors (default 2^(k/2), k = -8..4: 0.0625 .. 4)")
    p.add_argument("--threshold", type=float, default=0.01,
                   help="vibration threshold: fraction of torque power above --f-cut (default 0.01)")
    p.add_argument("--f-cut", type=float, default=50.0, help="vibration band starts here [Hz] (default 50)")
    p.add_argument("--duration", type=float, default=None, help="shorten every run [s] (default: the 2 s CPT)")
    p.add_argument("--rigid", action="store_true", help="rigid arm (the default)")
    p.add_argument("--flexible", action="store_true", help="flexible D2R2 (BUILD_NOTES 'Flexible D2R2')")
    p.add_argument("--workers", type=int, default=None, help="parallel runs (default: the core count)")
    add_output_flags(p, plot="DIR")
    p.set_defaults(func=run)


def _fmt_eps(d):
    if d is None:
        return "none on grid"
    return ", ".join(f"{k}={v:.3g}" for k, v in d.items())


def run(args) -> int:
    from robust_drake.errors import RobustDrakeError
    from robust_drake.experiments.epsilon_search import DEFAULT_FACTORS, TABLE1, epsilon_search, plot_search

    controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    bad = [c for c in controllers if c not in TABLE1]
    if bad or not controllers:
        raise RobustDrakeError(f"no table-1 epsilon for controller(s) {bad}; choose from {', '.join(TABLE1)}")
    if args.factors:
        try:
            factors = [float(x) for x in args.factors.split(",") if x.strip()]
        except ValueError:
            raise RobustDrakeError(f"--factors must be comma-separated numbers (got {args.factors!r})") from None
    else:
        factors = DEFAULT_FACTORS
    if args.duration is not None and not args.duration > 0.2:
        raise RobustDrakeError(f"--duration must exceed 0.2 s (the measure drops the first 0.1 s; got {args.duration})")
    if args.plot is not None and not args.plot.strip():
        raise RobustDrakeError("--plot is empty; give a folder path")
    models = [m for m, on in (("rigid", args.rigid), ("flexible", args.flexible)) if on] or ["rigid"]
    out = epsilon_search(controllers, factors, duration=args.duration, models=models, threshold=args.threshold,
                         f_cut=args.f_cut, workers=args.workers, progress=not args.json)
    if args.plot:
        out["plot"] = plot_search(out, args.plot)
    if args.json:
        print_json(out)
        return 0
    rows = []
    for r in out["results"]:
        rows.append([r["controller"], r["model"], _fmt_eps(r["epsilon"]),
                     "-" if r["factor"] is None else f"{r['factor']:.3g}",
                     "-" if r["vibration"] is None else f"{r['vibration']:.4f}",
                     "-" if r["error_task"] is None else f"{r['error_task']:.4g}", _fmt_eps(r["published"])])
    print(f"smallest epsilon without vibration (torque power above {out['f_cut']:g} Hz <= {out['threshold']:g} "
          f"on every joint, at it and every larger grid value); {out['setting']}")
    print(format_table(rows, ["controller", "model", "epsilon found", "x table 1", "vibration", "|error_task| [m]",
                              "published (JS table 1)"]))
    if out.get("plot"):
        print(f"figure: {out['plot']}")
    return 0
