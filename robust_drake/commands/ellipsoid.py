"""``robust-drake ellipsoid``: confidence ellipsoid of the IMI SCARA parameters (CI sections 3-5).

Simulated identification experiment (exciting trajectory, noise within the paper's bounds) or
measured data (``--data FILE.csv --bounds ...``), the SDP through Drake's MathematicalProgram,
and the sampling certificate.
"""

from __future__ import annotations

import numpy as np

from robust_drake.cli import add_output_flags, format_table, print_json
from robust_drake.errors import DataError, RobustDrakeError


def register(subparsers):
    p = subparsers.add_parser(
        "ellipsoid", help="confidence ellipsoid of the parameters (Calafiore & Indri SDP)",
        description="Identify the IMI SCARA's parameters from a simulated experiment (or --data) with "
                    "bounded errors on tau and qdd, solve for the minimal-trace ellipsoid containing every "
                    "least-squares solution (CI section 3.1, an SDP through Drake's MathematicalProgram), "
                    "certify it by sampling Delta, and print theta0, sqrt(P_ii) and trace(P).")
    p.add_argument("--robot", default="imi_scara", help="robot (only imi_scara has the section 5 regressor)")
    p.add_argument("--samples", type=int, default=5, help="number of samples n_m (default 5, as in the paper)")
    p.add_argument("--solver", default="clarabel", choices=["clarabel", "scs", "csdp"],
                   help="SDP solver (default clarabel; csdp with the drake backend only)")
    p.add_argument("--backend", default="drake", choices=["drake", "cvxpy", "direct"],
                   help="drake: MathematicalProgram (default); cvxpy; direct: pip clarabel")
    p.add_argument("--formulation", default="chordal", choices=["chordal", "full", "energy", "auto"],
                   help="chordal SDP (default); full dense SDP; energy: sound closed-form bound (~5 s at 1000 "
                        "samples, 2.2-4x the SDP's trace); auto: chordal up to 200 samples, energy above")
    p.add_argument("--draws", type=int, default=1000, help="Delta draws for the certificate (default 1000)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the simulated experiment and the certificate (default 0)")
    p.add_argument("--data", default=None, help="CSV with columns q1,q2,qd1,qd2,qdd1,qdd2,tau1,tau2")
    p.add_argument("--bounds", default=None,
                   help="delta_max as 'tau=4.5744,0.5459;qdd=0.5892,1.6478' (default: the paper's)")
    p.add_argument("--save", default=None, help="write theta0 and P to this JSON file")
    add_output_flags(p, plot=None)
    p.set_defaults(func=run)


def parse_bounds(text):
    out = {}
    for part in text.split(";"):
        if not part.strip():
            continue
        try:
            k, v = part.split("=")
            out[k.strip()] = np.array([float(x) for x in v.split(",")])
        except ValueError as exc:
            raise RobustDrakeError(f"cannot parse --bounds part {part!r}; use 'tau=a,b;qdd=c,d'") from exc
    return out


def _read_csv(path):
    import io
    import os

    import pandas as pd

    from robust_drake.identification.data import read_text

    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    try:  # read once (a pipe works), gzip/Latin-1 as the repair's reader
        df = pd.read_csv(io.StringIO(read_text(path)), comment="#", skipinitialspace=True)
    except DataError:
        raise
    except Exception as exc:  # pandas raises several types for garbage
        raise DataError(f"{path}: cannot read as CSV ({str(exc).strip().splitlines()[0]})") from None
    df.columns = [str(c).strip() for c in df.columns]
    cols = {s: [f"{s}1", f"{s}2"] for s in ("q", "qd", "qdd", "tau")}
    missing = [c for cs in cols.values() for c in cs if c not in df.columns]
    if missing:
        raise DataError(f"{path}: missing columns {missing} (need q1,q2,qd1,qd2,qdd1,qdd2,tau1,tau2)")
    need = [c for cs in cols.values() for c in cs]
    values = df[need].apply(pd.to_numeric, errors="coerce")
    bad = ~np.isfinite(values.to_numpy(float))
    if bad.any():
        r, c = (int(x[0]) for x in np.nonzero(bad))
        raise DataError(f"{path}: column {need[c]!r} at data row {r + 1} is missing or not a finite number "
                        f"(read as {str(df[need[c]].iloc[r])!r}; a line with fewer values than the header?)")
    if len(values) == 0:
        raise DataError(f"{path}: no data rows")
    return {s: values[c].to_numpy(float) for s, c in cols.items()} | {"theta_true": None}


def check_save_path(path) -> None:
    """Refuse a --save target that cannot be written, before the (long) computation."""
    import os

    if os.path.isdir(path):
        raise RobustDrakeError(f"--save {path}: is a directory; give a file name such as {os.path.join(path, 'ellipsoid.json')}")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise RobustDrakeError(f"--save {path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise RobustDrakeError(f"--save {path}: not writable")


def run(args) -> int:
    from robust_drake.experiments.calafiore import run_ellipsoid_experiment

    from robust_drake.description import describe

    if describe(args.robot).closed_form_regressor != "imi_scara":
        raise RobustDrakeError(f"ellipsoid: only robot imi_scara has the section 5 regressor (got {args.robot!r})")
    if args.samples < 1:
        raise RobustDrakeError("--samples must be >= 1")
    if args.draws < 1:
        raise RobustDrakeError(f"--draws must be >= 1 (got {args.draws}): every ellipsoid is certified by "
                               "sampling Delta; use e.g. --draws 100 for a quick run")
    if args.save:
        check_save_path(args.save)
    bounds = parse_bounds(args.bounds) if args.bounds else None
    data = _read_csv(args.data) if args.data else None
    from robust_drake.log import slow_step

    with slow_step(f"ellipsoid: {args.formulation} formulation, {args.backend}/{args.solver}, "
                   f"certificate with {args.draws} draws ..."):
        out = run_ellipsoid_experiment(args.samples, args.solver, args.seed, args.backend, args.formulation,
                                       args.draws, bounds=bounds, data=data)
    res = out.pop("_result")
    if args.save:
        res.ellipsoid.save(args.save)
    if args.json:
        print_json(out)
        return 0
    print(f"samples {out['n_samples']}, uncertain scalars {out['n_uncertain_scalars']}, solver {out['solver']} "
          f"({out['status']}), setup {out['setup_seconds']:.2f} s, solve {out['solve_seconds']:.2f} s")
    rows = [[i + 1, out["theta0"][i], float(np.sqrt(out["P"][i][i]))] for i in range(len(out["theta0"]))]
    print(format_table(rows, ["i", "theta0", "sqrt(P_ii)"]))
    c = out["containment"]
    print(f"trace(P) = {out['trace']:.4g}; certificate: {c['inside']}/{c['tested']} inside, max radius "
          f"{c['max_radius']:.4f}; true theta radius {out['true_theta_radius']}")
    return 0
