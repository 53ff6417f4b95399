"""Bascetta & Rocco section V case study: Case A vs Case B on the Siciliano two-link arm.

``run_case_study(gains=(25, 5))`` designs both controllers (bounds, beta of eqs. 13 and 20,
Lyapunov P of Case A, Riccati P0 of Case B with the lemma certificates), simulates both on the
trapezoidal Cartesian line with the model perturbation, logs w and rho, and returns the JSON
dictionary of the ``robust-drake bascetta`` contract:

    {"A": {"beta", "w_energy", "rho_peak", "rho_rms", "error_max", ...}, "B": {...},
     "riccati": {"gamma", "gamma_max", "P0", "residual", ...}, ...}

w_energy is the 2-norm of the sampled signal per joint, sqrt(sum_k w_k^2 T) (BR section V);
rho_rms = sqrt(mean rho_k^2); error_max = max_k |q_d - q| per joint [rad].
Plant: frictionless, exact positions and velocities (observer "exact"), no torque limit.
"""

from __future__ import annotations

import os

import numpy as np

from robust_drake.errors import RobustDrakeError


def short_horizon() -> bool:
    return os.environ.get("ROBUST_DRAKE_SHORT", "") not in ("", "0")


def simulate_case(case: str, gains=(25.0, 5.0), duration=None, boundary=0.01, perturbation=None,
                  trajectory_params=None, rate=2500.0, beta=None):
    """Run one case (``"A"`` or ``"B"``); returns ``(SimulationResult, controller)`` with
    ``result.extra["w"]`` (K x n) and ``result.extra["rho"]`` (K x 1) logged at the sample rate.
    ``beta`` overrides the case's (beta_0, beta_1, beta_2) (variants: scaled terms, constant rho)."""
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

    if case not in ("A", "B"):
        raise RobustDrakeError(f"case must be 'A' or 'B' (got {case!r})")
    kp, kd = float(gains[0]), float(gains[1])
    params = {"K_P": kp, "K_D": kd, "boundary": boundary}
    if perturbation is not None:
        params["perturbation"] = dict(perturbation)
    if beta is not None:
        params["beta"] = [float(b) for b in beta]
    cfg = ClosedLoopConfig(robot="siciliano_2link", controller=f"bascetta_{case.lower()}",
                           controller_params=params, trajectory="line",
                           trajectory_params=dict(trajectory_params or {}), observer="exact",
                           plant_friction=None, encoder_resolution=None, torque_limit=None,
                           rate=rate, duration=duration)
    cl = build_closed_loop(cfg)
    cl.add_log("w", cl.controller.GetOutputPort("w"))
    cl.add_log("rho", cl.controller.GetOutputPort("rho"))
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging loop says so (res.diverged), once
        res = cl.simulate()
    return res, cl.controller


def case_summary(res, ctrl) -> dict:
    """The per-case numbers of the JSON contract."""
    T = ctrl.period
    w = res.extra["w"]
    rho = res.extra["rho"][:, 0]
    err = res.q - res.q_d
    return {
        "beta": list(ctrl.beta),
        "w_energy": np.sqrt(np.sum(w**2, axis=0) * T).tolist(),
        "w_energy_total": float(np.sqrt(np.sum(w**2) * T)),
        "rho_peak": float(np.max(rho)),
        "rho_rms": float(np.sqrt(np.mean(rho**2))),
        "error_max": np.max(np.abs(err), axis=0).tolist(),
        "velocity_error_max": np.max(np.abs(res.v - res.qd_d), axis=0).tolist(),
        "torque_max": np.max(np.abs(res.u), axis=0).tolist(),
        "boundary": ctrl.boundary,
        "diverged": bool(res.diverged),
        "divergence_reason": getattr(res, "divergence_reason", None) if res.diverged else None,
        "wall_seconds": res.wall_seconds,
        "sim_seconds": res.sim_seconds,
    }


def check_gains(gains) -> tuple[float, float]:
    """``(K_P, K_D)`` as floats; refuses anything but two finite positive numbers (BR eqs. 5-6: the
    nominal error dynamics ``[[0, 1], [-K_P, -K_D]]`` is Hurwitz only for K_P, K_D > 0)."""
    try:
        kp, kd = (float(g) for g in gains)
    except (TypeError, ValueError):
        raise RobustDrakeError(f"gains must be two numbers (K_P, K_D), got {gains!r}") from None
    if not (np.isfinite(kp) and np.isfinite(kd) and kp > 0 and kd > 0):
        raise RobustDrakeError(
            f"gains K_P = {kp:g}, K_D = {kd:g} are not admissible: both must be finite and positive (BR eq. 6: "
            "the nominal error dynamics [[0, 1], [-K_P, -K_D]] is Hurwitz only for K_P, K_D > 0)")
    return kp, kd


def run_case_study(gains=(25.0, 5.0), duration=None, boundary=0.01, perturbation=None,
                   trajectory_params=None, lemma_check=True, keep_results=False) -> dict:
    """Both cases at ``gains = (K_P, K_D)`` (scalars, the same for both joints); see module doc."""
    from robust_drake.analysis import lemmas

    gains = check_gains(gains)

    out = {}
    results = {}
    for case in ("A", "B"):
        res, ctrl = simulate_case(case, gains, duration, boundary, perturbation, trajectory_params)
        out[case] = case_summary(res, ctrl)
        results[case] = (res, ctrl)
    d = results["B"][1].design
    ric = d["riccati"]
    out["riccati"] = {
        "gamma": ric.gamma, "gamma_max": ric.gamma_max, "P0": ric.P0.tolist(), "residual": ric.residual,
        "delta": ric.delta, "kappa01": ric.kappa01, "kappa02": ric.kappa02, "t_norm": ric.t_norm,
        "P0_eigs": np.linalg.eigvalsh(ric.P0).tolist(), "Pi": ric.Pi.tolist(),
    }
    if lemma_check:
        out["riccati"]["lemmas"] = lemmas.check_all(ric.kappa01, ric.kappa02, ric.delta, ric.gamma)
    lyap = d["lyapunov"]
    out["lyapunov"] = {"P": lyap.P.tolist(), "Q": lyap.Q.tolist(), "residual": lyap.residual}
    out["bounds"] = d["bounds"].to_dict()
    out["gains"] = {"K_P": float(gains[0]), "K_D": float(gains[1])}
    out["perturbation"] = d["perturbation"]
    out["M_hat"] = d["M_hat"].tolist()
    eA, eB = out["A"]["w_energy_total"], out["B"]["w_energy_total"]
    out["w_energy_reduction_B_vs_A"] = float(1.0 - eB / eA) if eA > 0 else float("nan")
    if keep_results:
        out["_results"] = results
    return out


def plot_case_study(study: dict, outdir, other: dict | None = None) -> list:
    """Write :func:`case_study_figures` as PNG files into ``outdir``; returns the paths written."""
    import pathlib

    outdir = pathlib.Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, fig in case_study_figures(study, other).items():
        fig.savefig(outdir / name, dpi=110)
        paths.append(str(outdir / name))
    return paths


def case_study_figures(study: dict, other: dict | None = None) -> dict:
    """Analogues of BR figs. 1-6 as matplotlib Figures, by file name (``fig3_w_base.png``, ...);
    ``other`` is a second study (other gains) for fig. 6. Needs ``keep_results=True`` studies.

    Figs. 3-4 (the additional control w per joint) add what the section compares and the two
    curves hide, lying within a line width of each other: the cumulative energy
    sqrt(int_0^t w_j^2 dt) of Case A and Case B and its relative difference (the paper reports
    11 % less for Case B, BR section V); figs. 5-6 add rho_B - rho_A."""
    from robust_drake.kinematics import planar_forward_kinematics
    from robust_drake.plotting import style, subplots

    (rA, cA), (rB, cB) = study["_results"]["A"], study["_results"]["B"]
    figures = {}
    g0 = study["gains"]
    gains = f"K_P = {g0['K_P']:g}, K_D = {g0['K_D']:g}"

    def save(fig, name):
        fig.tight_layout()
        figures[name] = fig

    with style():
        fig, ax = subplots(1, 1, figsize=(6.5, 3.6))
        ax.plot(rA.t, rA.q_d[:, 0], label="q1,d (base)")
        ax.plot(rA.t, rA.q_d[:, 1], label="q2,d (elbow)")
        ax.set_xlabel("t [s]"), ax.set_ylabel("[rad]"), ax.legend()
        ax.set_title("Fig. 1: joint-space trajectory")
        save(fig, "fig1_joint_trajectory.png")
        fig, ax = subplots(1, 1, figsize=(5.2, 5.2))
        p = planar_forward_kinematics(rA.q_d, (1.0, 1.0))
        ax.plot(p[:, 0], p[:, 1], lw=2)
        ax.plot(p[0, 0], p[0, 1], "ko", label="start")
        ax.set_aspect("equal"), ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]"), ax.legend()
        ax.set_title("Fig. 2: Cartesian trajectory")
        save(fig, "fig2_cartesian_trajectory.png")
        T = cA.period
        for j, (fname, label) in enumerate([("fig3_w_base.png", "base"), ("fig4_w_elbow.png", "elbow")]):
            fig, (a1, a2) = subplots(2, 1, figsize=(7.5, 5.6), sharex=True, height_ratios=(3, 2))
            wA, wB = rA.extra["w"][:, j], rB.extra["w"][:, j]
            a1.plot(rA.t, wA, color="C3", lw=1.6, label="Case A (BR eqs. 12-13)")
            a1.plot(rB.t, wB, color="C0", lw=1.0, ls=(0, (4, 2)), label="Case B (BR eqs. 17-20)")
            a1.set_ylabel("w [rad/s^2]"), a1.legend(loc="best")
            a1.set_title(f"Fig. {3 + j}: additional control w, {label} joint ({gains})")
            EA, EB = np.sqrt(np.cumsum(wA ** 2) * T), np.sqrt(np.cumsum(wB ** 2) * T)
            with np.errstate(invalid="ignore", divide="ignore"):
                rel = np.where(EA > 1e-9, 100.0 * (1.0 - EB / EA), np.nan)
            a2.plot(rA.t, rel, color="k", lw=1.2, label="Case B below Case A")
            a2.axhline(100 * PAPER_REDUCTION, color="C3", ls="--", lw=0.9, label="BR section V: 11 % (all joints)")
            a2.axhline(0.0, color="0.6", lw=0.8)
            from robust_drake.plotting import window_limits

            lo, hi = window_limits(rA.t, np.nan_to_num(rel), 0.1)  # the ratio of two near-zero energies at t ~ 0
            a2.set_ylim(min(lo, -1.0), max(hi, 100 * PAPER_REDUCTION + 2.0))
            a2.set_ylabel("energy of w so far:\n1 - E_B/E_A [%]"), a2.set_xlabel("t [s]")
            red = 1.0 - EB[-1] / EA[-1] if EA[-1] > 0 else float("nan")
            a2.set_title(f"E(t) = sqrt(int_0^t w^2 dt): Case B {100 * red:.1f} % below Case A at the end "
                         f"(all joints {100 * study.get('w_energy_reduction_B_vs_A', float('nan')):.1f} %)",
                         fontsize=9)
            a2.legend(loc="center right")
            save(fig, fname)
        for fnum, st in [(5, study), (6, other)]:
            if st is None:
                continue
            (ra, _), (rb, _) = st["_results"]["A"], st["_results"]["B"]
            fig, (a1, a2) = subplots(2, 1, figsize=(7.5, 5.2), sharex=True, height_ratios=(3, 2))
            a1.plot(ra.t, ra.extra["rho"][:, 0], color="C3", lw=1.6, label="Case A")
            a1.plot(rb.t, rb.extra["rho"][:, 0], color="C0", lw=1.0, ls=(0, (4, 2)), label="Case B")
            g = st["gains"]
            a1.set_ylabel("rho [rad/s^2]"), a1.legend()
            a1.set_title(f"Fig. {fnum}: gain rho, K_P = {g['K_P']:g}, K_D = {g['K_D']:g}")
            n = min(len(ra.t), len(rb.t))
            a2.plot(ra.t[:n], rb.extra["rho"][:n, 0] - ra.extra["rho"][:n, 0], color="k", lw=1.0)
            a2.axhline(0.0, color="0.6", lw=0.8)
            a2.set_ylabel("rho_B - rho_A\n[rad/s^2]"), a2.set_xlabel("t [s]")
            save(fig, f"fig{fnum}_rho_kp{g['K_P']:g}.png")
    return figures


# ============================================================================ section II-C: constant rho
def constant_rho(bounds, K_P, K_D, E_M: float) -> float:
    """BR section II-C, the constant gain of [3]: with ||n~|| <= Phi and ||e|| <= E_M,

        rho >= (alpha Q_M + alpha ||K|| E_M + B_M Phi) / (1 - alpha),

    Phi = alpha_0 + alpha_1 E_M + alpha_2 E_M^2 (the eq. 11 bound at ||e|| = E_M, the same sampled
    bounds as Cases A and B). ``E_M`` is an assumption on the tracking error; the study checks it."""
    from robust_drake.analysis.bascetta_bounds import gain_norm

    if not E_M > 0:
        raise RobustDrakeError(f"E_M (the assumed bound on ||e||) must be positive (got {E_M})")
    b = bounds
    phi = b.alpha_0 + b.alpha_1 * E_M + b.alpha_2 * E_M ** 2
    return float((b.alpha * b.Q_M + b.alpha * gain_norm(K_P, K_D) * E_M + b.B_M * phi) / (1.0 - b.alpha))


def run_constant_rho(gains=(25.0, 5.0), E_M: float = 0.2, duration=None, boundary=0.01, perturbation=None,
                     trajectory_params=None) -> dict:
    """Case A's Lyapunov P with the constant rho of section II-C; the case summary plus ``rho_constant``,
    ``E_M`` and ``assumption_held`` (max ||e|| along the run <= E_M)."""
    from robust_drake.systems.controllers.bascetta_rocco import case_study_design

    kp, kd = check_gains(gains)
    d = case_study_design("siciliano_2link", "line", trajectory_params, kp, kd, perturbation)
    rc = constant_rho(d["bounds"], kp, kd, E_M)
    res, ctrl = simulate_case("A", (kp, kd), duration, boundary, perturbation, trajectory_params, beta=(rc, 0.0, 0.0))
    out = case_summary(res, ctrl)
    e = np.hstack([res.q_d - res.q, res.qd_d - res.v])
    out.update(rho_constant=rc, E_M=float(E_M), e_norm_max=float(np.max(np.linalg.norm(e, axis=1))))
    out["assumption_held"] = bool(out["e_norm_max"] <= E_M)
    return out


# ============================================================================ sensitivity of the w-energy ratio
#: default one-at-a-time axes around the paper's setting (K_P, K_D) = (25, 5), boundary 0.01, our line
SENSITIVITY_AXES = {
    "boundary": [0.001, 0.003, 0.01, 0.03, 0.1],
    "gains": [(25.0, 5.0), (49.0, 7.0), (100.0, 10.0), (225.0, 15.0)],
    "length": [0.5, 1.0, 1.5],          # line length / default (about the same midpoint)
    "T": [1.0, 2.0, 4.0],               # travel time [s] (speed ~ length / T)
    "beta0_scale": [1.0, 0.5, 0.25, 0.1, 0.0],   # rho terms: beta_0 of both cases scaled
}
PAPER_REDUCTION = 0.11


def _line_params(length: float = 1.0, T: float = 2.0) -> dict:
    from robust_drake.models import get_arm

    L = sum(get_arm("siciliano_2link").link_lengths)
    s0, e0 = np.array([0.55 * L, 0.25 * L]), np.array([0.25 * L, 0.7 * L])
    m = (s0 + e0) / 2
    return {"start": (m + length * (s0 - m)).tolist(), "end": (m + length * (e0 - m)).tolist(), "T": float(T)}


def ratio_run(spec: dict) -> dict:
    """One point of the study (module-level, picklable): both cases, the energy reduction of w."""
    from robust_drake.systems.controllers.bascetta_rocco import case_study_design

    kp, kd = check_gains(spec["gains"])
    tp = _line_params(spec["length"], spec["T"])
    d = case_study_design("siciliano_2link", "line", tp, kp, kd, None)
    out = {}
    for case, key in (("A", "beta_A"), ("B", "beta_B")):
        beta = list(d[key])
        beta[0] *= spec["beta0_scale"]
        res, ctrl = simulate_case(case, (kp, kd), spec.get("duration"), spec["boundary"], None, tp, beta=beta)
        out[case] = case_summary(res, ctrl)
        out[case]["e_rms"] = float(np.sqrt(np.mean(np.sum((res.q_d - res.q) ** 2, axis=1))))
    eA, eB = out["A"]["w_energy_total"], out["B"]["w_energy_total"]
    return {**{k: spec[k] for k in ("axis", "value", "gains", "boundary", "length", "T", "beta0_scale")},
            "reduction": float(1.0 - eB / eA) if eA > 0 else float("nan"), "w_energy_A": eA, "w_energy_B": eB,
            "beta_A": out["A"]["beta"], "beta_B": out["B"]["beta"], "error_max_A": out["A"]["error_max"],
            "rho_rms_A": out["A"]["rho_rms"], "rho_rms_B": out["B"]["rho_rms"],
            "diverged": bool(out["A"]["diverged"] or out["B"]["diverged"]), "paper": PAPER_REDUCTION}


def sensitivity_specs(axes=None, duration=None) -> list[dict]:
    axes = SENSITIVITY_AXES if axes is None else axes
    base = {"gains": (25.0, 5.0), "boundary": 0.01, "length": 1.0, "T": 2.0, "beta0_scale": 1.0}
    specs = []
    for axis, values in axes.items():
        if axis not in base:
            raise RobustDrakeError(f"unknown sensitivity axis {axis!r}; known: {', '.join(base)}")
        for v in values:
            s = dict(base, axis=axis, value=v, duration=duration)
            s[axis] = tuple(v) if axis == "gains" else float(v)
            specs.append(s)
    return specs


def sensitivity_study(axes=None, duration=None, workers=None, progress=False) -> list[dict]:
    """The w-energy reduction of Case B vs Case A (BR section V: 11 %) one parameter at a time around
    (25, 5), boundary 0.01 rad, our default line (length 1, T = 2 s), full beta."""
    from robust_drake.parallel import run_parallel

    specs = sensitivity_specs(axes, duration)
    outs = run_parallel(ratio_run, specs, keys=[f"{s['axis']}={s['value']}" for s in specs], workers=workers,
                        desc="bascetta sensitivity", progress=progress)
    rows = []
    for s, o in zip(specs, outs):
        rows.append(o.value if o.ok else {"axis": s["axis"], "value": s["value"], "reduction": float("nan"),
                                          "diverged": True, "error": o.error, "paper": PAPER_REDUCTION})
    return rows


from robust_drake.plotting import styled  # noqa: E402 - the shared figure style


@styled
def plot_sensitivity(rows: list[dict], path) -> str:
    import pathlib

    from robust_drake.plotting import subplots

    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    axes_names = list(dict.fromkeys(r["axis"] for r in rows))
    fig, axes = subplots(1, len(axes_names), figsize=(3.2 * len(axes_names), 3.4), squeeze=False)
    for ax, name in zip(axes[0], axes_names):
        rs = [r for r in rows if r["axis"] == name]
        xs = [r["value"][0] if name == "gains" else r["value"] for r in rs]
        ax.plot(xs, [100 * r["reduction"] for r in rs], "o-")
        ax.axhline(100 * PAPER_REDUCTION, color="r", lw=0.8, ls="--", label="paper 11 %")
        if name == "boundary":
            ax.set_xscale("log")
        ax.set(xlabel={"gains": "K_P (K_D = sqrt K_P)", "boundary": "boundary layer [rad]",
                       "length": "line length / default", "T": "travel time T [s]",
                       "beta0_scale": "beta_0 scale"}.get(name, name), ylabel="w energy, B below A [%]")
    axes[0][0].legend(fontsize=8.5)
    fig.suptitle("Bascetta & Rocco: energy of w, Case B vs Case A (one parameter at a time)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return str(path)
