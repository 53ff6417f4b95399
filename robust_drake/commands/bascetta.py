"""``robust-drake bascetta``: the Bascetta & Rocco section V case study, Case A vs Case B."""

from __future__ import annotations

from robust_drake.cli import add_output_flags, format_table, print_json
from robust_drake.errors import RobustDrakeError


def _gains(text):
    from robust_drake.experiments.bascetta import check_gains

    try:
        kp, kd = (float(x) for x in text.split(","))
    except ValueError:
        raise RobustDrakeError(f"--gains must be 'KP,KD' (two numbers), got {text!r}") from None
    return check_gains((kp, kd))


def register(sub):
    p = sub.add_parser("bascetta", help="Bascetta & Rocco case study: classical (A) vs Riccati (B) robust inverse dynamics",
                       description="Design Case A (eq. 13) and Case B (eqs. 17-20) robust inverse dynamics for the "
                                   "Siciliano two-link arm, check Lemmas 1-5, simulate both on the trapezoidal "
                                   "Cartesian line with a perturbed model, and report beta, the energy of w, rho "
                                   "and the tracking errors.")
    p.add_argument("--gains", default="25,5", help="K_P,K_D for both joints (default 25,5; the paper also uses 100,10); "
                                                   "both must be positive")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s] (default: the trajectory's)")
    p.add_argument("--boundary", type=float, default=0.01,
                   help="boundary-layer width of z/||z|| in error units (default 0.01)")
    p.add_argument("--mass-scale", type=float, default=1.2,
                   help="factor on both link masses in the model used for n_hat (default 1.2)")
    p.add_argument("--constant-rho", type=float, default=None, metavar="E_M",
                   help="also run section II-C's constant rho with the assumed error bound ||e|| <= E_M")
    p.add_argument("--sensitivity", action="store_true",
                   help="instead of the case study: the w-energy reduction (B vs A) one parameter at a time "
                        "(boundary, gains, line length, travel time, beta_0 scale); --plot DIR draws it")
    p.add_argument("--workers", type=int, default=None, help="parallel runs of --sensitivity")
    add_output_flags(p, plot="DIR", files="fig1_joint_trajectory.png, fig2_cartesian_trajectory.png, "
                                          "fig3_w_base.png, fig4_w_elbow.png, ... (w_energy_sensitivity.png with --sensitivity)")
    p.set_defaults(func=run)


def _run_sensitivity(args) -> int:
    import os

    from robust_drake.experiments.bascetta import plot_sensitivity, sensitivity_study

    from robust_drake.cli import plot_dir

    plots = plot_dir(args)
    rows = sensitivity_study(duration=args.duration, workers=args.workers, progress=not args.json)
    plot = plot_sensitivity(rows, os.path.join(str(plots), "w_energy_sensitivity.png")) if plots is not None else None
    if args.json:
        print_json({"rows": rows, "plot": plot})
        return 0
    table = []
    for r in rows:
        v = r["value"]
        table.append([r["axis"], f"{v[0]:g},{v[1]:g}" if r["axis"] == "gains" else f"{v:g}",
                      "FAILED" if "error" in r else f"{100 * r['reduction']:.1f}",
                      "11", "-" if "error" in r else f"{max(r['error_max_A']):.3g}",
                      "-" if "error" in r else f"{r['beta_A'][0]:.3g}/{r['beta_A'][1]:.3g}/{r['beta_B'][1]:.3g}"])
    print("energy of w, Case B below Case A [%], one parameter at a time from (K_P, K_D) = (25, 5), boundary 0.01, "
          "line length 1, T = 2 s, full beta")
    print(format_table(table, ["axis", "value", "reduction %", "paper %", "max e_A rad", "beta0 / beta1 A / beta1 B"]))
    if plot:
        print(f"plot: {plot}")
    return 1 if any("error" in r for r in rows) else 0


def run(args) -> int:
    from robust_drake.experiments.bascetta import plot_case_study, run_case_study, run_constant_rho

    from robust_drake.cli import plot_dir
    from robust_drake.log import slow_step

    if args.sensitivity:
        return _run_sensitivity(args)
    gains = _gains(args.gains)
    plots = plot_dir(args)
    if not args.mass_scale > 0:
        raise RobustDrakeError("--mass-scale must be positive")
    pert = {"link1": args.mass_scale, "link2": args.mass_scale}
    keep = plots is not None
    with slow_step(f"bascetta: Case A and Case B with K_P, K_D = {gains[0]:g}, {gains[1]:g} ..."):
        study = run_case_study(gains, duration=args.duration, boundary=args.boundary, perturbation=pert,
                               keep_results=keep)
    paths = []
    if plots is not None:
        other_gains = (100.0, 10.0) if gains != (100.0, 10.0) else (25.0, 5.0)
        with slow_step(f"bascetta: K_P, K_D = {other_gains[0]:g}, {other_gains[1]:g} for the figures ..."):
            other = run_case_study(other_gains, duration=args.duration, boundary=args.boundary,
                                   perturbation=pert, lemma_check=False, keep_results=True)
        paths = plot_case_study(study, plots, other)
        study.pop("_results", None)
        study["plots"] = paths
    if args.constant_rho is not None:
        study["constant_rho"] = run_constant_rho(gains, args.constant_rho, args.duration, args.boundary, pert)
    diverged = study["A"]["diverged"] or study["B"]["diverged"]
    if args.json:
        print_json(study)
        return 1 if diverged else 0
    r = study["riccati"]
    print(f"Bascetta & Rocco case study, K_P = {gains[0]:g}, K_D = {gains[1]:g}, n_hat from link masses x {args.mass_scale:g}")
    b = study["bounds"]
    print(f"bounds: alpha = {b['alpha']:.4g}, B_M = {b['B_M']:.4g}, Q_M = {b['Q_M']:.4g}, "
          f"alpha_0..2 = {b['alpha_0']:.4g}, {b['alpha_1']:.4g}, {b['alpha_2']:.4g}")
    print(f"Riccati: delta = {r['delta']:.4g}, kappa = ({r['kappa01']:.4g}, {r['kappa02']:.4g}), gamma = {r['gamma']:.4g}, "
          f"gamma_max = {r['gamma_max']:.4g}, residual = {r['residual']:.2e}, eig(P0) = {r['P0_eigs']}")
    if "lemmas" in r:
        print("lemmas: " + ", ".join(f"{k} {'ok' if v['ok'] else 'FAILS'}" for k, v in r["lemmas"].items()))
    rows = []
    for case in ("A", "B"):
        s = study[case]
        rows.append([case, *[f"{x:.4g}" for x in s["beta"]], *[f"{x:.4g}" for x in s["w_energy"]],
                     s["rho_peak"], s["rho_rms"], *[f"{x:.3g}" for x in s["error_max"]]])
    print(format_table(rows, ["case", "beta0", "beta1", "beta2", "|w1|_2", "|w2|_2", "rho_peak", "rho_rms",
                              "emax1 rad", "emax2 rad"]))
    for case in ("A", "B"):
        if study[case]["diverged"]:
            reason = study[case].get("divergence_reason")
            print(f"Case {case} DIVERGED{f' ({reason})' if reason else ''}: its errors and energies above are those of "
                  "a blown-up run; lower the gains or shorten the sample period")
    if diverged:
        print("energy of w, Case B vs Case A: not compared (a diverged case has no meaningful energy; paper: 11 %)")
    else:
        print(f"energy of w, Case B vs Case A: {100 * study['w_energy_reduction_B_vs_A']:.1f} % lower (paper: 11 %)")
    if "constant_rho" in study:
        c = study["constant_rho"]
        print(f"constant rho (section II-C, ||e|| <= E_M = {c['E_M']:g}): rho = {c['rho_constant']:.4g}, "
              f"|w|_2 = {c['w_energy_total']:.4g} (Case A {study['A']['w_energy_total']:.4g}, "
              f"+{100 * (c['w_energy_total'] / study['A']['w_energy_total'] - 1):.1f} %), max ||e|| = "
              f"{c['e_norm_max']:.3g} ({'within' if c['assumption_held'] else 'OUTSIDE'} E_M) "
              f"(paper: no number; the constant bound is the conservative one)")
    for p_ in paths:
        print(f"plot: {p_}")
    return 1 if diverged else 0
