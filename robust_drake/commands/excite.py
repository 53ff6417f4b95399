"""``robust-drake excite``: design an informative, safe identification experiment for an arm.

A periodic, band-limited Fourier motion (Swevers et al. 1997) starting and ending at rest at a
given pose, optimised with Drake's MathematicalProgram (SNOPT) for log det of the information of
the base parameters plus friction (and ``--for-effects`` kinds), within the joint position,
velocity, acceleration and torque limits and free of collisions where the URDF has collision
geometry (``robust_drake.excitation.design``).  Writes the reference at the robot's rate
(``--out``: CSV ``t, q1..qn, qd1..qdn, qdd1..qddn``), prints a short report (condition number,
log det, predicted standard deviation of every parameter against the default excitation of the
same duration, the limits' margins), draws it with ``--plot DIR``.  ``robust-drake simulate
--robot R --trajectory traj.csv`` rehearses the experiment in simulation.
"""

from __future__ import annotations

from robust_drake.cli import add_output_flags, format_table, print_json
from robust_drake.errors import RobustDrakeError


def register(sub):
    p = sub.add_parser(
        "excite", help="design an optimal, safe identification excitation (Fourier, log det, limits, collisions)",
        description="Design a periodic, band-limited excitation for an arm's identification: maximal log det "
                    "of the information of the base parameters and friction, within joint position, velocity, "
                    "acceleration and torque limits and free of collisions, at rest at the start pose at both ends.",
        epilog="example: robust-drake excite panda --duration 10 --out traj.csv --plot out/excite; "
               "then robust-drake simulate --robot panda --controller sp1 --trajectory traj.csv")
    p.add_argument("robot", help="robot name (shipped in robust_drake/robots/) or a URDF path")
    p.add_argument("--duration", type=float, default=10.0,
                   help="experiment length [s], a whole number of periods (default 10)")
    p.add_argument("--out", default=None, help="write the reference CSV here (t, q1.., qd1.., qdd1.. at the robot's rate)")
    p.add_argument("--period", type=float, default=None,
                   help="period [s] (default: the duration up to 10 s, else the duration split into equal periods <= 10 s)")
    p.add_argument("--harmonics", type=int, default=None,
                   help="harmonics per joint (default: as many as fit below --max-frequency, at most 8)")
    p.add_argument("--max-frequency", type=float, default=None,
                   help="band limit [Hz] (default 2, a quarter of the identification filter's 8 Hz cut-off)")
    p.add_argument("--start", default=None,
                   help="rest pose q1,q2,... [rad] at both ends (default: the middle of each joint's limits, 0 without)")
    p.add_argument("--velocity-limit", default=None,
                   help="velocity limits [rad/s], one number or one per joint (default: the URDF's)")
    p.add_argument("--acceleration-limit", default=None,
                   help="acceleration limits [rad/s^2], one number or one per joint (default: none)")
    p.add_argument("--torque-limit", default=None,
                   help="torque limits [N m], one number or one per joint (default: the robot description's)")
    p.add_argument("--torque-fraction", type=float, default=0.8,
                   help="share of the torque limits the model torque may use (default 0.8: headroom for the tracking loop)")
    p.add_argument("--for-effects", default="",
                   help="effect kinds added to the information, comma separated (e.g. position_dependent,stribeck,"
                        "rotor_inertia)")
    p.add_argument("--min-distance", type=float, default=0.01,
                   help="smallest distance between collision geometries [m] (default 0.01)")
    p.add_argument("--rate", type=float, default=None, help="CSV rate [Hz] (default: the robot description's sample_rate)")
    p.add_argument("--starts", type=int, default=1, help="random starting points of the optimiser (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the starting point and of the default excitation (default 0)")
    add_output_flags(p, plot="DIR", files="excitation.png, information.png")
    p.set_defaults(func=run)


def _numbers(text, option):
    if text is None:
        return None
    try:
        vals = [float(x) for x in str(text).replace(" ", "").split(",") if x]
    except ValueError:
        raise RobustDrakeError(f"{option} takes numbers separated by commas (got {text!r})") from None
    if not vals:
        raise RobustDrakeError(f"{option} takes numbers separated by commas (got {text!r})")
    return vals[0] if len(vals) == 1 else tuple(vals)


def run(args) -> int:
    from robust_drake.cli import plot_dir
    from robust_drake.excitation.design import ExcitationConfig, design_excitation

    if args.starts < 1:
        raise RobustDrakeError(f"--starts must be at least 1 (got {args.starts})")
    if not 0 < args.torque_fraction <= 1:
        raise RobustDrakeError(f"--torque-fraction must lie in (0, 1] (got {args.torque_fraction})")
    start = _numbers(args.start, "--start")
    cfg = ExcitationConfig(
        robot=args.robot, duration=args.duration, period=args.period, harmonics=args.harmonics,
        max_frequency=args.max_frequency, start=None if start is None else tuple(start) if isinstance(start, tuple) else (start,),
        velocity_limits=_numbers(args.velocity_limit, "--velocity-limit"),
        acceleration_limits=_numbers(args.acceleration_limit, "--acceleration-limit"),
        torque_limits=_numbers(args.torque_limit, "--torque-limit"), torque_fraction=args.torque_fraction,
        effects=tuple(k for k in args.for_effects.split(",") if k.strip()), min_distance=args.min_distance,
        rate=args.rate, seed=args.seed, starts=args.starts)
    plots = plot_dir(args)
    res = design_excitation(cfg)
    out = res.to_dict()
    if args.out:
        out["out"] = res.to_csv(args.out)
    if plots is not None:
        out["plots"] = res.plot(plots)
    if args.json:
        print_json(out)
        return 0
    _print_text(out)
    return 0


def _print_text(out: dict) -> None:
    import numpy as np

    m = out["margins"]
    print(f"excitation for {out['robot']}: {out['duration']:g} s ({out['periods']} x {out['period']:g} s period), "
          f"{out['harmonics']} harmonics up to {out['max_frequency_hz']:.3g} Hz, start {np.round(out['start'], 4).tolist()}")
    print(f"log det {out['log_det']:.2f} (default excitation {out['default']['log_det']:.2f}), condition number "
          f"{out['condition_number']:.3g} (default {out['default']['condition_number']:.3g}); predicted std "
          f"smaller by a median {out['median_std_ratio']:.3g}x, geometric mean "
          f"{out['volume_ratio_per_parameter']:.3g}x (torque noise {out['noise_std']:.3g} N m per sample at "
          f"{out['rate']:g} Hz)")
    rows = []
    for j, name in enumerate(out["joint_names"]):
        f = lambda key: m[key]["fraction_of_limit"][j] if m[key].get("fraction_of_limit") else None  # noqa: E731
        rows.append([j, name, min(m["position"]["min_to_lower"][j], m["position"]["min_to_upper"][j]),
                     f("velocity"), f("acceleration"), f("torque")])
    print(format_table(rows, ["joint", "name", "to position box rad", "velocity/limit", "acceleration/limit",
                              "torque/limit"]))
    d = m["distance"]
    print("collisions: " + (f"smallest distance {d['min']:.4g} m ({d['pair']}) over {d['collision_pairs']} pairs"
                            if d.get("min") is not None else d.get("note", "")))
    worst = sorted(zip(out["parameters"], out["std_ratio"]), key=lambda kv: kv[1])[:3]
    print("least improved: " + ", ".join(f"{k} {v:.3g}x" for k, v in worst)
          + f"; solver {out['solver']['solver']} {out['solver']['status']} in {out['solver']['seconds']:.1f} s"
          + (f"; motion scaled by {out['scale']:.3f}" if out["scale"] < 1 else ""))
    if out.get("effects_left_out"):
        print(f"left out (inside the base parameters' span): {', '.join(out['effects_left_out'])}")
    if out.get("out"):
        print(f"reference: {out['out']}")
    for pth in out.get("plots", []):
        print(f"plot: {pth}")
