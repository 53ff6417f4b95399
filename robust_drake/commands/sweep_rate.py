"""``robust-drake sweep-rate``: the sample-rate study proposed in JS section 11.

Runs the chosen controllers (same gains, table 1 epsilons, the same n = 3 averaging filter) on
the CPT with friction compensation at each sample rate and prints |error_task| (JS eq. 58),
maxerr_task and a chattering measure (total variation of the torque per second, summed over the
joints) per rate; ``--plot DIR`` writes ``DIR/sweep_rate.png`` (both against the rate).

Defaults differ from ``simulate`` on purpose: friction compensation is on (JS section 11 uses
the compensated CPT of tables 4-5); the table header says so.
"""

from __future__ import annotations

import sys

from robust_drake.cli import add_output_flags, format_table, print_json


def register(sub):
    p = sub.add_parser("sweep-rate", help="JS section 11: tracking and chattering of SP1/SP2/ZC as the sample rate falls",
                       description="Run each controller (same gains, JS table 1 epsilons, n = 3 averaging filter) "
                                   "at each sample rate and print |error_task| (JS eq. 58), maxerr_task (eq. 59) "
                                   "and the torque's total variation per second (chattering). Friction "
                                   "compensation (JS eqs. 89-90) is ON by default here, unlike 'simulate'.")
    p.add_argument("--controllers", default="sp1,sp2,zc", help="comma-separated controllers (default sp1,sp2,zc)")
    p.add_argument("--rates", default="250,500,1000,2500,5000",
                   help="comma-separated sample rates [Hz] (default 250,500,1000,2500,5000)")
    p.add_argument("--trajectory", default="cpt", choices=["cpt", "circle"], help="reference (default cpt)")
    p.add_argument("--load", default="none", choices=["none", "max"], help="arm load (default none)")
    p.add_argument("--no-friction-compensation", action="store_true", help="drop the fixed compensation of JS eqs. 89-90 (on by default here)")
    p.add_argument("--duration", type=float, default=None, help="shorten every run [s]")
    p.add_argument("--workers", type=int, default=None, help="parallel runs (default: the core count)")
    add_output_flags(p, plot="DIR", files="sweep_rate.png")
    p.set_defaults(func=run)


def _parse_rates(text):
    from robust_drake.errors import RobustDrakeError

    try:
        rates = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise RobustDrakeError(f"--rates must be comma-separated numbers of Hz (got {text!r})") from None
    if not rates or any(not r > 0 for r in rates):
        raise RobustDrakeError(f"--rates must be positive numbers of Hz (got {text!r})")
    return rates


def run(args) -> int:
    from robust_drake.errors import RobustDrakeError
    from robust_drake.experiments import jaritz_spong as js
    from robust_drake.registry import names

    from robust_drake.cli import plot_dir, show_progress

    plots = plot_dir(args)
    controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    bad = [c for c in controllers if c not in names("controller")]
    if bad or not controllers:
        raise RobustDrakeError(f"unknown controller(s) {bad}; known: {', '.join(names('controller'))}")
    rates = _parse_rates(args.rates)
    if args.duration is not None and not args.duration > 0:
        raise RobustDrakeError(f"--duration must be positive (got {args.duration})")
    rows = js.sweep_rate(controllers, rates, workers=args.workers, progress=show_progress(args),
                         trajectory=args.trajectory, load=args.load,
                         friction_compensation=not args.no_friction_compensation, duration=args.duration)
    plot = str(js.plot_sweep(rows, plots / "sweep_rate.png")) if plots is not None else None
    if args.json:
        print_json(rows)
    else:
        body = []
        for r in rows:
            status = "FAILED" if "error" in r else ("diverged" if r["diverged"] else "ok")
            body.append([js.LABELS.get(r["controller"], r["controller"]), f"{r['rate']:g}",
                         f"{r['error_task']:.4g}", f"{r['maxerr_task']:.4g}", f"{r['chattering']:.4g}", status])
        print(f"Sample-rate study (JS section 11): {args.trajectory}, load {args.load}, "
              f"friction compensation {'off' if args.no_friction_compensation else 'on'}"
              + ("" if args.no_friction_compensation else " (simulate's default is off)"))
        print(format_table(body, ["algorithm", "rate [Hz]", "|error_task| [m]", "maxerr_task [m]",
                                  "torque TV [N m/s]", "status"]))
        if plot:
            print(f"plot: {plot}")
    for r in rows:
        if "error" in r:
            print(f"run failed: {r['controller']} at {r['rate']:g} Hz: {r['error']}", file=sys.stderr)
    return 1 if any("error" in r for r in rows) else 0
