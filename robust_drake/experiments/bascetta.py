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
    """Analogues of BR figs. 1-6 as PNG files in ``outdir``; ``other`` is a second study (other
    gains) for fig. 6. Needs ``keep_results=True`` studies. Returns the paths written."""
    import pathlib

    from robust_drake.kinematics import planar_forward_kinematics
    from robust_drake.plotting import subplots

    outdir = pathlib.Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    (rA, cA), (rB, cB) = study["_results"]["A"], study["_results"]["B"]
    paths = []

    def save(fig, name):
        p = outdir / name
        fig.tight_layout()
        fig.savefig(p, dpi=120)
        paths.append(str(p))

    fig, ax = subplots(1, 1, figsize=(6, 3.5))
    ax.plot(rA.t, rA.q_d[:, 0], label="q1_d")
    ax.plot(rA.t, rA.q_d[:, 1], label="q2_d")
    ax.set_xlabel("t [s]"), ax.set_ylabel("rad"), ax.legend(), ax.set_title("Fig. 1: joint space trajectory")
    save(fig, "fig1_joint_trajectory.png")
    fig, ax = subplots(1, 1, figsize=(5, 5))
    p = planar_forward_kinematics(rA.q_d, (1.0, 1.0))
    ax.plot(p[:, 0], p[:, 1])
    ax.set_aspect("equal"), ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]"), ax.set_title("Fig. 2: Cartesian trajectory")
    save(fig, "fig2_cartesian_trajectory.png")
    for j, (fname, label) in enumerate([("fig3_w_base.png", "base"), ("fig4_w_elbow.png", "elbow")]):
        fig, ax = subplots(1, 1, figsize=(7, 3.5))
        ax.plot(rA.t, rA.extra["w"][:, j], "r-", lw=0.8, label="Case A")
        ax.plot(rB.t, rB.extra["w"][:, j], "b:", lw=1.0, label="Case B")
        ax.set_xlabel("t [s]"), ax.set_ylabel("w [rad/s^2]"), ax.legend()
        ax.set_title(f"Fig. {3 + j}: additional control w, {label} joint")
        save(fig, fname)
    for fnum, st in [(5, study), (6, other)]:
        if st is None:
            continue
        (ra, _), (rb, _) = st["_results"]["A"], st["_results"]["B"]
        fig, ax = subplots(1, 1, figsize=(7, 3.5))
        ax.plot(ra.t, ra.extra["rho"][:, 0], "r-", label="Case A")
        ax.plot(rb.t, rb.extra["rho"][:, 0], "b:", label="Case B")
        g = st["gains"]
        ax.set_xlabel("t [s]"), ax.set_ylabel("rho [rad/s^2]"), ax.legend()
        ax.set_title(f"Fig. {fnum}: gain rho, K_P = {g['K_P']:g}, K_D = {g['K_D']:g}")
        save(fig, f"fig{fnum}_rho_kp{g['K_P']:g}.png")
    return paths


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
    axes[0][0].legend(fontsize=7)
    fig.suptitle("Bascetta & Rocco: energy of w, Case B vs Case A (one parameter at a time)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return str(path)
