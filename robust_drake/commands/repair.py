"""``robust-drake repair``: identify, analyse the residual, add missing effects, report before/after.

::

    robust-drake repair FIT.csv [FIT2.csv ...] --robot NAME_OR_URDF [--validate VAL.csv ...]
                        [--torque tau_meas|tau_con] [--cutoff HZ]
                        [--velocities differentiated|logged] --out DIR [--force] [--json] [--plot DIR2]

Writes ``DIR/report.md``, ``DIR/report.json`` and (unless ``--no-plots``) the residual plots
``residual_fit.png``, ``residual_validate.png``, ``torque_validate.png`` (and
``estimator_cutoff.png``); ``--plot DIR2`` also copies those PNG files into DIR2. Progress goes
to stderr (``-q`` silences it), the JSON of ``--json`` alone to stdout. CSVs: canonical (``t, q1..qn, tau1..taun``) or DFKI records.
The report is built in a temporary folder beside DIR and moved into place when complete; an
earlier report in DIR is replaced only with ``--force``. Warnings (poor excitation, unpowered
joint, units, little data, frozen joint, prismatic joint) are printed as ``warning: ...`` lines
on stderr and listed in ``report.json["warnings"]`` and report.md.
"""

from __future__ import annotations

import os
import sys

from robust_drake.cli import add_output_flags, format_table, non_negative, print_json
from robust_drake.joints import joint_text


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "repair",
        help="identify a model from measured data, find and add missing effects, report before/after",
        description=__doc__.split("::")[0].strip(),
    )
    p.add_argument("fit", nargs="+", metavar="FIT.csv", help="fit data (canonical or DFKI CSV)")
    p.add_argument("--robot", required=True, help="robot name in models/ or a URDF path")
    p.add_argument("--validate", nargs="+", metavar="VAL.csv", default=None,
                   help="validation data (default: hold out the last 25%% of every fit file)")
    p.add_argument("--torque", choices=("tau_meas", "tau_con"), default="tau_meas",
                   help="DFKI torque column (ignored for canonical CSVs)")
    p.add_argument("--cutoff", type=float, default=None, metavar="HZ",
                   help="zero-phase low-pass cut-off for q and tau (default 8 Hz)")
    p.add_argument("--velocities", choices=("differentiated", "logged"), default="differentiated",
                   help="differentiated (default): velocities and accelerations from the filtered "
                        "positions; logged: low-pass the log's velocity columns qd1..qdn (a real "
                        "velocity sensor, e.g. a motor encoder's speed) and differentiate them once")
    p.add_argument("--effects", default=None, metavar="K1,K2",
                   help="restrict the candidate effect kinds (default: the whole library)")
    p.add_argument("--min-gain", type=non_negative(float, "--min-gain"), default=None,
                   help="minimum relative held-out error reduction to add an effect (default 0.05)")
    p.add_argument("--max-effects", type=non_negative(int, "--max-effects"), default=4,
                   help="add at most this many effects (default 4)")
    p.add_argument("--no-consistent", action="store_true",
                   help="skip the physically consistent (pseudo-inertia LMI) estimate")
    p.add_argument("--no-instruments", action="store_true",
                   help="skip the errors-in-variables test (least squares vs instrumental variables)")
    p.add_argument("--no-nominal", action="store_true",
                   help="skip the comparison with the URDF's parameters (effects inside the rigid-body "
                        "span, e.g. payload, and the joint of a torque_scale error)")
    p.add_argument("--sigma-rel", type=float, default=None, metavar="FRAC",
                   help="relative trust in the URDF's base parameters for that comparison (default 0.05)")
    p.add_argument("--level", type=float, default=None, metavar="P",
                   help="confidence level of every decision from the data (accept an effect, call a model worse, "
                        "flag a setup change; paired block tests, Holm over joints; default 0.95)")
    p.add_argument("--no-replay", action="store_true", help="skip the replay through the Drake plant")
    p.add_argument("--no-plots", action="store_true", help="do not write PNG plots")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--force", action="store_true",
                   help="replace an earlier report in --out (its plots are removed with it) and an earlier --export-urdf file")
    p.add_argument("--export-urdf", metavar="FILE.urdf", default=None,
                   help="also write the repaired model as a URDF (physically consistent link inertials, rotor "
                        "inertias, joint friction) and FILE.identified.yaml (friction and the effects a URDF cannot "
                        "hold); refused when no physically consistent body exists")
    add_output_flags(p, plot="DIR", files="residual_fit.png, residual_validate.png, torque_validate.png "
                                          "(copies of the report's plots in --out)")
    p.set_defaults(func=run)


def run(args) -> int:
    from robust_drake.errors import OptionError, RobustDrakeError
    from robust_drake.identification.data import DEFAULT_CUTOFF_HZ
    from robust_drake.model_repair.pipeline import CLI_FLAGS, RepairOptions, run_repair
    from robust_drake.model_repair.report import signal
    from robust_drake.model_repair.selection import MIN_GAIN

    try:  # one validation for the command line and rd.repair (RepairOptions.validate)
        opts = RepairOptions(
            robot=args.robot, torque=args.torque,
            velocities="logged" if args.velocities == "logged" else "positions",
            cutoff_hz=DEFAULT_CUTOFF_HZ if args.cutoff is None else args.cutoff,
            kinds=args.effects, min_gain=MIN_GAIN if args.min_gain is None else args.min_gain,
            max_effects=args.max_effects, consistent=not args.no_consistent, replay=not args.no_replay,
            plots=not args.no_plots, nominal=not args.no_nominal, instruments=not args.no_instruments,
            **({} if args.sigma_rel is None else {"sigma_rel": args.sigma_rel}),
            **({} if args.level is None else {"level": args.level}),
        )
    except OptionError as exc:
        raise RobustDrakeError(exc.as_flag(CLI_FLAGS.get(exc.option, exc.option))) from None
    from robust_drake.cli import plot_dir

    _check_export(args)
    if args.plot is not None and args.no_plots:
        raise RobustDrakeError("--plot and --no-plots contradict each other")
    plots = plot_dir(args)
    from robust_drake.allocator import reuse_freed_memory

    reuse_freed_memory()  # large temporaries reused instead of re-mapped (allocator.py: ~25 % of the CPU)
    log = None  # progress lines -> the robust_drake logger -> stderr (-q silences them)
    try:
        rep = run_repair(args.fit, opts, validate_paths=args.validate, out_dir=args.out, progress=log,
                         overwrite=args.force, cli=True)
    except OptionError as exc:
        raise RobustDrakeError(exc.as_flag(CLI_FLAGS.get(exc.option, exc.option))) from None
    if plots is not None:
        rep["plot_copies"] = _copy_plots(rep.get("plots") or [], args.out, plots)
    _export(args, rep)
    for w in rep.get("warnings") or []:  # the same list as report.json["warnings"] and report.md
        print(f"warning: {w}", file=sys.stderr)
    if args.json:
        print_json(rep)
        return 0
    n = len(rep["baseline"]["rms_fit"])
    rows = [["baseline", *rep["baseline"]["rms_fit"], *rep["baseline"]["rms_validate"]]]
    for e in rep["effects"]:
        rows.append([f"+ {e['kind']}[{'all' if e['joint'] is None else e['joint'] + 1}]", *([""] * n), *e["rms_validate_after"]])
    rows.append(["repaired", *rep["final"]["rms_fit"], *rep["final"]["rms_validate"]])
    header = ["model", *[f"fit j{j + 1}" for j in range(n)], *[f"val j{j + 1}" for j in range(n)]]  # joints from 1
    print(f"robot {rep['robot']}, {rep['samples']} fit samples, RMS torque residual [N m]:")
    print(format_table(rows, header))
    print(f"verdict: {rep['verdict']} ({rep['verdict_reason']})")
    for d in rep.get("rejected_effects") or []:
        print(f"  dropped {d['label']}: {d['reason']}")
    print(f"unexplained_structure: {str(rep['unexplained_structure']).lower()}"
          + (f" ({', '.join(signal(w['variable']) + ' on ' + joint_text(w['joint'], rep.get('joint_names')) for w in rep['unexplained_where'])})"
             if rep["unexplained_structure"] else ""))
    est = rep.get("estimator") or {}
    if est.get("hausman"):
        print(f"estimator: {est['method']} (Hausman {est['hausman']['statistic']:.1f}, "
              f"1 % limit {est['hausman']['limit']:.1f})")
    nom = rep.get("nominal")
    if nom:
        print(f"URDF parameters: shift chi2 {nom['chi2']:.1f} (99 % limit {nom['chi2_limit']:.1f}), "
              + (f"explained by {nom['named']}" if nom.get("named") else
                 "not explained by a payload or rotor inertia" if nom["unexplained_shift"] else "not significant")
              + f"; URDF-model validate {[round(x, 4) for x in nom['rms_validate']]}")
    rp = rep.get("replay") or {}
    if rp.get("before") and rp.get("after"):
        print(f"replay RMS q error [rad]: before {[round(x, 4) for x in rp['before']['rms_q']]}, "
              f"after {[round(x, 4) for x in rp['after']['rms_q']]}")
    print(f"report: {os.path.join(args.out, 'report.md')}")
    _print_export(rep.get("export"))
    return 0


def _copy_plots(files, out, plots) -> list:
    """Copies of the report's plots (paths relative to ``out``) in ``plots`` (--plot DIR)."""
    import shutil

    copies = []
    for f in files:
        src, dst = os.path.join(out, f), plots / os.path.basename(f)
        if os.path.isfile(src):
            if not (dst.exists() and os.path.samefile(src, dst)):  # --plot = --out: already there
                shutil.copy(src, dst)
            copies.append(str(dst))
    return copies


def _check_export(args) -> None:
    """One-line errors for --export-urdf before the repair runs (name, --no-consistent, no overwrite)."""
    from robust_drake.errors import RobustDrakeError

    if args.export_urdf is None:
        return
    if not str(args.export_urdf).lower().endswith(".urdf"):
        raise RobustDrakeError(f"--export-urdf takes a file name ending in .urdf (got {args.export_urdf!r})")
    if args.no_consistent:
        raise RobustDrakeError("--export-urdf writes the physically consistent fit, which --no-consistent switches off")
    if os.path.exists(args.export_urdf) and not args.force:
        raise RobustDrakeError(f"{args.export_urdf} exists; pass --force to replace it")


def _export(args, rep) -> None:
    """--export-urdf: the repaired model's URDF + sidecar (``IdentifiedModel.to_urdf``), into rep["export"]."""
    if args.export_urdf is not None:
        from robust_drake.identification.model import IdentifiedModel

        rep["export"] = IdentifiedModel.from_report(rep).to_urdf(args.export_urdf)


def _print_export(ex) -> None:
    if not ex:
        return
    print(f"exported: {ex['urdf']} (+ {ex['sidecar']}: friction"
          + (f", {', '.join(ex['effects_in_sidecar'])}" if ex["effects_in_sidecar"] else "") + ")")
    for note in ex["notes"]:
        print(f"  note: {note}")
