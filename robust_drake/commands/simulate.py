"""``robust-drake simulate``: one closed loop, the six error criteria of JS section 4."""

from __future__ import annotations

from robust_drake.cli import add_output_flags, format_table, non_negative, print_json
from robust_drake.errors import RobustDrakeError
from robust_drake.metrics import METRIC_KEYS


def register(sub):
    p = sub.add_parser("simulate", help="run one closed loop and print the JS error criteria",
                       description="Run one closed loop (plant + friction + encoder + observer + controller "
                                   "+ saturation) and print |error_n|, maxerr_n, |error_task|, maxerr_task "
                                   "(Jaritz & Spong eqs. 55, 56, 58, 59).")
    p.add_argument("--robot", default="d2r2", help="robot name (URDFs shipped in robust_drake/robots/) or a URDF path (default d2r2)")
    p.add_argument("--load", default="none", help="load variant: none | max (default none)")
    p.add_argument("--controller", default="sp1", help="controller name (pd, sp1, sp2, ...; default sp1)")
    p.add_argument("--trajectory", default="cpt",
                   help="cpt | circle | refmodel | sine | step | line, or a trajectory file FILE.csv (t, q1.., qd1.., "
                        "qdd1..: what 'robust-drake excite --out' writes) (default cpt)")
    p.add_argument("--trajectory-param", action="append", default=[], metavar="KEY=VALUE",
                   help="a parameter of the trajectory factory, repeatable; VALUE is YAML, e.g. amplitude=0.3, "
                        "offset=[0,0,0,-1.57,0,1.87,0] (sine/step/cpt/refmodel; default offset: q = 0 where "
                        "inside the joint limits, else the middle of the range)")
    p.add_argument("--observer", default="averaging", help="velocity estimator (default averaging, JS eqs. 64/66)")
    p.add_argument("--rate", type=float, default=None,
                   help="controller/observer sample rate [Hz] (default: the robot description's sample_rate, "
                        "else 2500; the D2R2 2500, the Panda 1000)")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s] (default: the trajectory's)")
    p.add_argument("--skip", type=non_negative(float, "--skip"), default=None,
                   help="ignore the first SKIP s in the metrics (default 0; for the circle 1 s as in JS section 10, "
                        "or a seventh of a shorter --duration, as compare does)")
    p.add_argument("--friction-compensation", action="store_true",
                   help="add the fixed compensation of JS eqs. 89-90 (default off, as in compare's tables 2-3; "
                        "sweep-rate turns it on)")
    m = p.add_mutually_exclusive_group()
    m.add_argument("--rigid", action="store_true", help="rigid arm (default)")
    m.add_argument("--flexible", action="store_true",
                   help="D2R2 only: two-mass drives, motor-side encoders, link-2 bending (BUILD_NOTES 'Flexible D2R2')")
    p.add_argument("--model", metavar="REPORT", default=None,
                   help="the controller's model: a repair's report.json (or its folder) or a model file; SP1, SP2, "
                        "calafiore and bascetta_a/b take theta0 and their set from it (--json prints them), its "
                        "friction and effects are compensated")
    p.add_argument("--plant-model", metavar="REPORT", default=None,
                   help="simulate the identified arm: its rigid body, friction and effects (a report.json or model file)")
    p.add_argument("--design", metavar="FILE", default=None,
                   help="run the loop of a design file written by robust-drake control (its nominal run; "
                        "--duration still applies, the other loop options come from the file)")
    p.add_argument("--diagram", metavar="FILE", default=None,
                   help="write the closed loop's block diagram: FILE.svg/.png/.pdf (needs Graphviz's dot) "
                        "or FILE.dot (the source)")
    p.add_argument("--meshcat", nargs="?", const="live", default=None, metavar="FILE.html",
                   help="show the arm in Meshcat (pydrake's browser viewer on localhost) and record the run; "
                        "with FILE.html also write a self-contained replay of it (open it in any browser, "
                        "no server; play it from 'Open Controls'). The live server stays up for "
                        "--meshcat-wait S, or on a terminal until Enter")
    p.add_argument("--meshcat-wait", type=non_negative(float, "--meshcat-wait"), default=None, metavar="S",
                   help="keep the live Meshcat server up S seconds after the run (default: until Enter on a "
                        "terminal, 0 otherwise)")
    p.add_argument("--animation", metavar="FILE", default=None,
                   help="planar 2-link arms: a stick-figure animation of the run, FILE.gif or FILE.html "
                        "(matplotlib; no browser needed)")
    add_output_flags(p, plot="DIR", files="tracking.png, task_path.png (planar 2-link arms)")
    p.set_defaults(func=run)


def run(args) -> int:
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

    from robust_drake.cli import plot_dir

    plots = plot_dir(args)
    if args.rate is not None and not args.rate > 0:
        raise RobustDrakeError(f"--rate must be positive (got {args.rate})")
    flex = None
    if args.flexible:
        from robust_drake.description import describe

        if describe(args.robot).flexibility is None:
            raise RobustDrakeError(f"--flexible needs flexibility parameters in the robot's description; {args.robot!r} "
                                   "has none (the D2R2 has; use ClosedLoopConfig.flexibility for other arms)")
        from robust_drake.systems.flexibility import d2r2_flexibility

        flex = d2r2_flexibility(args.load, robot=args.robot)
    cfg, design = _design_config(args) if args.design else (None, None)
    if cfg is None:
        cfg = ClosedLoopConfig(robot=args.robot, load=args.load, controller=args.controller,
                               trajectory=args.trajectory, trajectory_params=_key_values(args.trajectory_param,
                                                                                         "--trajectory-param"),
                               observer=args.observer, **({} if args.rate is None else {"rate": args.rate}),
                               duration=args.duration, metrics_skip=_metrics_skip(args),
                               friction_compensation=args.friction_compensation, flexibility=flex,
                               model=args.model, plant_model=args.plant_model)
    loop = build_closed_loop(cfg)
    c = loop.config
    args.rate = float(c.rate)  # the description's sample rate when --rate is not given
    args.robot, args.load, args.trajectory, args.friction_compensation = c.robot, c.load, c.trajectory, c.friction_compensation
    args.controller = c.to_dict()["controller"]
    import sys

    from robust_drake.log import slow_step

    _check_view_options(args)
    meshcat = vis = None
    if args.meshcat:
        from robust_drake.viz import add_meshcat

        meshcat, vis = add_meshcat(loop)
        print(f"meshcat: {meshcat.web_url()}", file=sys.stderr)

    with slow_step(f"simulating {args.controller} on {args.robot}, {args.trajectory}, {args.rate:g} Hz ..."):
        res = loop.simulate()
    views = _save_views(args, loop, res, meshcat, vis)
    if args.diagram:
        from robust_drake.viz import render_diagram

        print(f"diagram: {render_diagram(loop, args.diagram)}", file=sys.stderr)
    plot = None
    if plots is not None:
        from robust_drake.plotting import plot_tracking, task_path_figure

        plot = str(plot_tracking(res, plots / "tracking.png"))
        if res.link_lengths:  # planar 2-link arm: the end effector's path too
            task_path_figure(res).savefig(plots / "task_path.png", dpi=110)
    out = res.to_dict()
    out.update(robot=args.robot, load=args.load, controller=args.controller, trajectory=args.trajectory,
               rate=args.rate, model="flexible" if args.flexible else "rigid")
    # the parameter uncertainty set behind a robust controller's bound (None for others)
    unc = getattr(loop.controller, "uncertainty", None)
    rho = getattr(loop.controller, "rho", None)
    out.update(uncertainty=unc, rho=rho if unc is not None else None)
    out["reference"] = dict(loop.reference.params)  # with the offset the joint limits chose
    out.update(_model_output(args, loop, design))
    if plot:
        out["plots"] = [plot] + ([str(plots / "task_path.png")] if res.link_lengths else [])
    out.update(views)
    if args.json:
        print_json(out)
    else:
        _print_text(args, out, loop, res, plot)
    if vis is not None:
        _keep_server(args, meshcat)
    return 1 if res.diverged else 0


def _check_view_options(args) -> None:
    """--meshcat FILE.html, --meshcat-wait S (needs --meshcat), --animation FILE.gif|.html."""
    if args.meshcat_wait is not None and args.meshcat is None:
        raise RobustDrakeError("--meshcat-wait needs --meshcat")
    if args.meshcat not in (None, "live") and not args.meshcat.lower().endswith((".html", ".htm")):
        raise RobustDrakeError(f"--meshcat takes a .html file name for the replay (got {args.meshcat!r}), "
                               "or nothing for the live viewer only")
    if args.animation and not args.animation.lower().endswith((".gif", ".html")):
        raise RobustDrakeError(f"--animation takes a .gif or .html file name (got {args.animation!r})")


def _save_views(args, loop, res, meshcat, vis) -> dict:
    """After the run: publish the Meshcat recording (and write its replay), write the animation;
    returns the JSON keys ``meshcat_replay`` / ``animation`` of the files written."""
    import sys

    out = {}
    if vis is not None:
        from robust_drake.viz import publish_recording, save_replay

        if args.meshcat != "live":
            out["meshcat_replay"] = str(save_replay(meshcat, vis, args.meshcat, loop=loop, result=res))
            print(f"meshcat replay: {out['meshcat_replay']}", file=sys.stderr)
        else:
            publish_recording(vis)
    if args.animation:
        from robust_drake.viz import save_animation

        if not res.link_lengths:
            raise RobustDrakeError("--animation draws planar 2-link arms; use --meshcat FILE.html for this arm")
        out["animation"] = str(save_animation(res, args.animation))
        print(f"animation: {out['animation']}", file=sys.stderr)
    return out


def _keep_server(args, meshcat) -> None:
    """Keep the live Meshcat server up: --meshcat-wait S seconds, else until Enter on a terminal."""
    import sys
    import time

    if args.meshcat_wait is not None:
        if args.meshcat_wait > 0:
            print(f"meshcat: serving {meshcat.web_url()} for {args.meshcat_wait:g} s (Ctrl-C stops)", file=sys.stderr)
            time.sleep(args.meshcat_wait)
    elif sys.stdin.isatty():
        input("Meshcat: replay the recording in the browser; press Enter to stop the server ")
    elif args.meshcat == "live":
        print("meshcat: no terminal, so the live server stops now; keep it up with --meshcat-wait S or "
              "save a replay with --meshcat FILE.html", file=sys.stderr)
def _model_output(args, loop, design) -> dict:
    """The identified models and the design file a run used (for --json)."""
    out = {}
    if args.model or args.plant_model:
        out.update(controller_model=args.model, plant_model=args.plant_model,
                   not_compensated=dict(loop.not_compensated or getattr(loop.controller, "not_compensated", {}) or {}))
    if design is not None:
        out.update(design_file=args.design, design_nominal=design.get("nominal"))
    return out


def _design_config(args):
    """(ClosedLoopConfig, design document) of ``--design FILE``; --duration overrides the file's."""
    import dataclasses

    import yaml

    from robust_drake.diagram import ClosedLoopConfig

    if args.model or args.plant_model or args.flexible:
        raise RobustDrakeError("--design takes the whole loop from the file; drop --model / --plant-model / --flexible")
    cfg = ClosedLoopConfig.from_yaml(args.design)
    with open(args.design) as fh:
        doc = yaml.safe_load(fh)
    if args.duration is not None:
        cfg = dataclasses.replace(cfg, duration=args.duration)
    return cfg, doc if isinstance(doc, dict) else {}


def _metrics_skip(args) -> float:
    """--skip, else 0; on the circle 1 s as JS section 10, or a seventh of a shorter --duration."""
    from robust_drake.experiments.jaritz_spong import CIRCLE_SKIP

    if args.skip is not None:
        return args.skip
    if args.trajectory != "circle":
        return 0.0
    return CIRCLE_SKIP if args.duration is None else min(CIRCLE_SKIP, args.duration / 7.0)


def _print_text(args, out, loop, res, plot) -> None:
    """The run as text: one line about it, the criteria (JS eqs. 55, 56, 58, 59 for a 2-link arm,
    one row per joint otherwise), the uncertainty set of a robust controller, the plot."""
    print(f"{args.controller} on {args.robot}{' (flexible)' if args.flexible else ''} (load {args.load}), "
          f"{args.trajectory}, {args.rate:g} Hz, friction compensation {'on' if args.friction_compensation else 'off'}, "
          f"{res.sim_seconds:.2f} s simulated in {res.wall_seconds:.2f} s"
          + (f"  ** DIVERGED: {res.divergence_reason} **" if res.diverged else ""))
    if loop.n == 2:  # JS eqs. 55, 56, 58, 59 as the paper tabulates them
        print(format_table([[out[k] for k in METRIC_KEYS]],
                           ["|error1| rad", "maxerr1 rad", "|error2| rad", "maxerr2 rad", "|error_task| m",
                            "maxerr_task m"]))
    else:  # one row per joint, 0-based with its URDF name (JSON keys error1..errorN: JS eq. 55's)
        names = loop.joint_limits.names
        print(format_table([[j, names[j], out.get(f"error{j + 1}"), out.get(f"maxerr{j + 1}")]
                            for j in range(loop.n)], ["joint", "name", "|error| rad", "maxerr rad"]))
    if out.get("uncertainty") is not None:
        unc = out["uncertainty"]
        print(f"uncertainty: {unc.get('kind')} ({unc.get('source', '')}), rho = {out['rho']}")
    if plot:
        print(f"plot: {plot}")


def _key_values(items, option: str) -> dict:
    """``["k=v", ...]`` -> {k: YAML value of v}; a one-line error for an item without ``=``."""
    import yaml

    out = {}
    for item in items:
        key, eq, text = item.partition("=")
        if not eq or not key.strip():
            raise RobustDrakeError(f"{option} takes KEY=VALUE (got {item!r})")
        try:
            out[key.strip()] = yaml.safe_load(text)
        except yaml.YAMLError:
            raise RobustDrakeError(f"{option} {key.strip()}: {text!r} is not a YAML value") from None
    return out
