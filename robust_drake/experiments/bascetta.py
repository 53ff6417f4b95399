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
                  trajectory_params=None, rate=2500.0):
    """Run one case (``"A"`` or ``"B"``); returns ``(SimulationResult, controller)`` with
    ``result.extra["w"]`` (K x n) and ``result.extra["rho"]`` (K x 1) logged at the sample rate."""
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

    if case not in ("A", "B"):
        raise RobustDrakeError(f"case must be 'A' or 'B' (got {case!r})")
    kp, kd = float(gains[0]), float(gains[1])
    params = {"K_P": kp, "K_D": kd, "boundary": boundary}
    if perturbation is not None:
        params["perturbation"] = dict(perturbation)
    cfg = ClosedLoopConfig(robot="siciliano_2link", controller=f"bascetta_{case.lower()}",
                           controller_params=params, trajectory="line",
                           trajectory_params=dict(trajectory_params or {}), observer="exact",
                           plant_friction=None, encoder_resolution=None, torque_limit=None,
                           rate=rate, duration=duration)
    cl = build_closed_loop(cfg)
    cl.add_log("w", cl.controller.GetOutputPort("w"))
    cl.add_log("rho", cl.controller.GetOutputPort("rho"))
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
