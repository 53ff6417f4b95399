"""``robust-drake control REPORT.json --controller ci|sp1|sp2``: a robust controller designed from
an identified model and its confidence set, checked by Monte Carlo over plants drawn from the set
(with the identified friction and effects), the design written as YAML for ``simulate --design``.

The model is a repair's ``report.json`` (or its folder) or a model file
(``IdentifiedModel.save``). The last line (and ``--json``'s ``guaranteed`` / ``verdict``) says
whether every drawn plant stayed within its per-joint ultimate bound; the exit status is 1 when not.
"""

from __future__ import annotations

import os

from robust_drake.cli import add_output_flags, format_table, print_json
from robust_drake.errors import RobustDrakeError


def register(sub):
    p = sub.add_parser(
        "control", help="identified model -> robust controller from its confidence set -> Monte Carlo within the bound",
        description="Design Calafiore & Indri's eq. 15 (ci) or Spong's SP1 / SP2 from an identified model (a repair's "
                    "report.json or a model file) and its confidence set, run plants drawn across the set (half on "
                    "its boundary, each a physically valid arm with the identified friction and effects) against "
                    "the per-joint ultimate tracking-error bound, and write the design as YAML (simulate --design "
                    "reruns it). Example: robust-drake control out/repair_c1/report.json --controller ci")
    p.add_argument("model", metavar="REPORT", help="report.json of a repair (or its folder), or a model file")
    p.add_argument("--controller", default="ci", choices=("ci", "sp1", "sp2"),
                   help="ci: CI eq. 15 on the ellipsoid; sp1/sp2: JS eqs. 18 / SP2, rho from it (default ci)")
    p.add_argument("--alpha", type=float, default=0.01, help="1 - confidence level of the set (default 0.01)")
    p.add_argument("--draws", type=int, default=8, help="Monte Carlo plants inside the set (default 8)")
    p.add_argument("--boundary-share", type=float, default=0.5,
                   help="share of the draws on the boundary of the set, the rest uniform inside (default 0.5)")
    p.add_argument("--track-duration", type=float, default=2.0, help="closed-loop run per draw [s] (default 2)")
    p.add_argument("--transient", type=float, default=1.0, help="the bound is checked after this time [s] (default 1)")
    p.add_argument("--rate", type=float, default=None, help="controller rate [Hz] (default: the robot description's)")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    p.add_argument("--design", metavar="FILE", default=None,
                   help="design YAML to write (default: design_<controller>.yaml beside the report)")
    p.add_argument("--force", action="store_true", help="replace an existing design file")
    add_output_flags(p, plot="DIR", files="control.png (error and bound per draw)")
    p.set_defaults(func=run)


def design_path(args) -> str:
    """--design, else ``design_<controller>.yaml`` in the report's folder; an existing file is
    refused without --force (nothing overwritten without asking)."""
    path = args.design
    if path is None:
        base = args.model if os.path.isdir(args.model) else os.path.dirname(os.path.abspath(args.model))
        path = os.path.join(base, f"design_{args.controller}.yaml")
    if os.path.exists(path) and not args.force:
        raise RobustDrakeError(f"{path} exists; choose another --design or pass --force to replace it")
    return path


def run(args) -> int:
    from robust_drake.cli import plot_dir
    from robust_drake.experiments.control import ControlConfig, run_control

    cfg = ControlConfig(controller=args.controller, alpha=args.alpha, draws=args.draws,
                        boundary_share=args.boundary_share, track_duration=args.track_duration,
                        transient=args.transient, rate=args.rate, seed=args.seed)
    cfg.check()
    cfg.design = design_path(args)
    plots = plot_dir(args)
    out = run_control(args.model, cfg)
    if plots is not None:
        from robust_drake.experiments.logs_to_control import plot_logs_to_control

        out["plot"] = plot_logs_to_control(out, plots / "control.png")
    if args.json:
        print_json(out)
        return 0 if out["guaranteed"] else 1
    d = out["design"]
    print(f"{out['robot']}: {args.controller} ({d['registry_controller']}) from the {100 * (1 - args.alpha):g} % set of "
          f"the identified model ({out['estimator']}, {out['samples']} samples), rho = {out['rho']:.4g}, "
          f"{d['rate']:g} Hz")
    print_draws(out)
    print(f"design: {out['design_file']} (robust-drake simulate --design {out['design_file']})")
    print(f"verdict: {out['verdict']}")
    return 0 if out["guaranteed"] else 1


def print_draws(out: dict) -> None:
    """The draws' table, the boundary layer, PD's error and the per-joint bound (the lines of
    ``logs-to-control``)."""
    print(f"{out['rejected']} draws no rigid body realises were redrawn, "
          f"{sum(d['projected'] for d in out['draws'])} replaced by the nearest valid point of the set")
    rc = (out.get("epsilon_rule") or {}).get("recentred")
    if rc:
        print(f"the identified centre is no rigid-body arm: eq. 15 is designed on the nearest one in the set "
              f"(radius {rc['radius']:.3f}) with the set inflated {rc['inflation']:.3g}x to keep all of it")
    eps = out["epsilon_rule"].get("epsilon")
    prev = out["epsilon_rule"].get("previous_rule_epsilon")
    print(f"boundary layer epsilon {_num(eps)}" + (f" (previous rule {prev:.4g})" if prev is not None else "")
          + f"; M(q) over {region_text(out['region'])}")
    rows = [[i, d["kind"] + (" (nearest valid)" if d["projected"] else ""), d["radius"], d["bound"], d["max_error"],
             d["ratio"], "yes" if d["within"] else "NO"] for i, d in enumerate(out["draws"])]
    print(format_table(rows, ["draw", "where", "radius", "bound [rad]", "max |e| [rad]", "bound / |e|",
                              "every joint within"]))
    worst = [max(d["bound_per_joint"][j] for d in out["draws"]) for j in range(len(out["K"]))]
    print("per-joint bound [rad] (largest over the draws): " + ", ".join(f"joint {j + 1} {b:.4g}" for j, b in enumerate(worst)))
    print(f"PD (same K, Lambda) max |e| after the transient: {out['pd_max_error']:.4g} rad")


def _num(x) -> str:
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(f"{v:.4g}" for v in x) + "]"
    return f"{x:.4g}" if isinstance(x, (int, float)) else str(x)


def region_text(r) -> str:
    if r["kind"] == "global":
        return f"a global grid of joints {r['joints']}"
    return (f"the reference tube +- {r['delta']} rad (bound {'inside' if r.get('consistent') else 'OUTSIDE'} "
            "the tube)")
