"""Calafiore & Indri (CI, seeds/000) section 5: simulated identification -> confidence ellipsoid
-> robust control study on the IMI SCARA (section 5.2).

* :func:`simulate_identification`: an exciting multi-sine trajectory (the paper's Fig. 2 is of
  this kind), exact torques tau = D(q, qd, qdd) theta_true from the section 5 regressor, noise
  uniform within the paper's bounds on tau and qdd (the signals the paper keeps uncertain), and
  the n_m samples chosen from a dense grid by greedy D-optimal selection (max log det D^T D of
  the measured regressor; CI's reference [4] designs the experiment for the same purpose).
* :func:`run_ellipsoid_experiment`: the above, the uncertainty model, the SDP and its certificate.
* :func:`run_study`: nominal (eq. 6) against robust (eq. 15) control on step references
  smoothed by a second-order filter, with "true" parameters drawn on the ellipsoid boundary and
  put into the Drake plant (link-2 mass/centre of mass/inertia and joint-1 rotor inertia for
  theta_1..4, the plant-side Coulomb + viscous block for theta_5..8).
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

from robust_drake.errors import RobustDrakeError

#: "true" arm for the simulated identification: the URDF's inertial parameters (the physically
#: realisable point nearest to the published theta0, see models/imi_scara.urdf) and the
#: published friction with a dissipative sigma_v2 (the printed -0.24 would feed energy in).
IMI_THETA_TRUE = np.array([4.9545, -0.1252, 0.254, 0.028, 1.4, 12.12, 1.9, 0.24])


def exciting_trajectory(t):
    """Multi-sine joint trajectory (rad, rad/s, rad/s^2), shape (K, 2) each."""
    t = np.asarray(t, dtype=float)
    w = np.array([[1.1, 2.3, 3.7], [1.3, 2.9, 4.3]])
    A = np.array([[0.9, 0.5, 0.3], [1.0, 0.6, 0.35]])
    ph = np.array([[0.0, 1.0, 2.0], [0.5, 1.7, 2.9]])
    arg = t[:, None, None] * w[None] + ph[None]
    q = (A * np.sin(arg)).sum(-1)
    qd = (A * w * np.cos(arg)).sum(-1)
    qdd = -(A * w * w * np.sin(arg)).sum(-1)
    return q, qd, qdd


def d_optimal_indices(D, count: int) -> np.ndarray:
    """Greedy D-optimal choice of ``count`` samples from D (K, n, m): maximise log det sum D_k^T D_k."""
    K, n, m = D.shape
    if count > K:
        raise RobustDrakeError(f"cannot choose {count} samples out of {K}")
    G = 1e-6 * np.eye(m)
    chosen = []
    free = np.ones(K, bool)
    for _ in range(count):
        Ginv = np.linalg.inv(G)
        # log det(G + Dk^T Dk) - log det G = log det(I + Dk Ginv Dk^T)
        S = np.einsum("kim,mn,kjn->kij", D, Ginv, D) + np.eye(n)
        gain = np.linalg.slogdet(S)[1]
        gain[~free] = -np.inf
        k = int(np.argmax(gain))
        chosen.append(k)
        free[k] = False
        G = G + D[k].T @ D[k]
    return np.sort(np.array(chosen))


def simulate_identification(n_samples: int, seed: int = 0, bounds=None, theta_true=None, duration: float = 20.0,
                            grid: int = 4000):
    """Measured samples (q, qd, qdd, tau) with noise within ``bounds`` (default CI_BOUNDS)."""
    from robust_drake.uncertainty.regression import CI_BOUNDS
    from robust_drake.regressor import imi_scara_regressor

    bounds = CI_BOUNDS if bounds is None else bounds
    theta_true = IMI_THETA_TRUE if theta_true is None else np.asarray(theta_true, dtype=float)
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration, max(grid, n_samples))
    q, qd, qdd = exciting_trajectory(t)
    tau = np.einsum("kij,j->ki", imi_scara_regressor(q, qd, qdd), theta_true)
    meas = {"q": q.copy(), "qd": qd.copy(), "qdd": qdd.copy(), "tau": tau.copy()}
    for sig, b in bounds.items():
        if b is not None:
            meas[sig] = meas[sig] + rng.uniform(-1.0, 1.0, meas[sig].shape) * np.asarray(b, dtype=float)
    D = imi_scara_regressor(meas["q"], meas["qd"], meas["qdd"])
    idx = d_optimal_indices(D, n_samples) if n_samples < len(t) else np.arange(len(t))
    return {k: v[idx] for k, v in meas.items()} | {"t": t[idx], "theta_true": theta_true}


def run_ellipsoid_experiment(n_samples: int = 5, solver: str = "clarabel", seed: int = 0, backend: str = "drake",
                             formulation: str = "chordal", draws: int = 1000, bounds=None, data=None) -> dict:
    """Identification -> uncertainty model -> SDP -> certificate; the ``robust-drake ellipsoid`` JSON."""
    from robust_drake.uncertainty.ellipsoid import result_to_dict, solve_ellipsoid
    from robust_drake.uncertainty.regression import CI_BOUNDS, build_uncertainty_model
    from robust_drake.regressor import imi_scara_regressor

    bounds = CI_BOUNDS if bounds is None else bounds
    if data is None:
        data = simulate_identification(n_samples, seed, bounds=bounds)
    t0 = time.perf_counter()
    model = build_uncertainty_model(imi_scara_regressor, data["q"], data["qd"], data["qdd"], data["tau"], bounds)
    t_model = time.perf_counter() - t0
    res = solve_ellipsoid(model, solver=solver, formulation=formulation, backend=backend, certify_draws=draws,
                          seed=seed)
    out = result_to_dict(res)
    out["setup_seconds"] = res.setup_seconds + t_model
    out["n_samples"] = model.n_samples
    out["n_uncertain_scalars"] = model.n_scalars
    out["true_theta_radius"] = (float(res.ellipsoid.radius(data["theta_true"])) if data.get("theta_true") is not None
                                else None)
    out["theta_ls"] = np.linalg.lstsq(model.D0.reshape(-1, model.n_params), model.tau0.reshape(-1),
                                      rcond=None)[0].tolist()
    # CI section 3: the stacked regressor must keep full column rank for every admissible delta
    from robust_drake.uncertainty.full_rank import check_full_rank
    out["full_rank"] = check_full_rank(model, draws=200, seed=seed).to_dict()
    out["_result"] = res
    return out


# ============================================================================ control study
def set_imi_theta(plant, context, theta) -> None:
    """Put CI theta[0:4] = [Gamma1z + m2 l1^2, m2 s2x, m2 s2y, Gamma2z] into the IMI plant context.

    Link 2 keeps m2 when Gamma2z > m2 |s2|^2 allows (else m2 is raised), its centre of mass is
    (theta2, theta3) / m2 and its central izz Gamma2z - m2 |s2|^2; link 1 is unchanged and the rest
    of theta1 is the joint-1 rotor inertia (as in models/imi_scara.urdf).
    """
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia

    from robust_drake.models import _joint2_offset

    th1, th2, th3, th4 = (float(x) for x in np.asarray(theta, dtype=float)[:4])
    j1, j2, l1 = _joint2_offset(plant)
    b1, b2 = j1.child_body(), j2.child_body()
    m2 = b2.get_mass(context)
    s2 = th2 * th2 + th3 * th3
    if not th4 > 0:
        raise RobustDrakeError(f"Gamma2z = {th4} <= 0 is not physically realisable")
    if s2 / m2 >= 0.9 * th4:
        m2 = s2 / (0.5 * th4)
    c = np.array([th2 / m2, th3 / m2, 0.0])
    Izz = th4 - s2 / m2
    b2.SetSpatialInertiaInBodyFrame(context, SpatialInertia.MakeFromCentralInertia(
        m2, c, RotationalInertia(0.5 * Izz, 0.5 * Izz, Izz)))
    # link-1 inertia about joint 1 (body frame origin on the joint axis) + m2 l1^2
    I1 = float(b1.CalcSpatialInertiaInBodyFrame(context).CalcRotationalInertia().CopyToFullMatrix3()[2, 2])
    base = I1 + m2 * l1 * l1
    Ir = th1 - base
    if Ir < 0:
        raise RobustDrakeError(f"theta1 = {th1} is smaller than the link inertias ({base:.4f})")
    act1 = [plant.get_joint_actuator(a) for a in plant.GetJointActuatorIndices()
            if plant.get_joint_actuator(a).joint().index() == j1.index()][0]
    act1.SetGearRatio(context, 1.0)
    act1.SetRotorInertia(context, Ir)


def physical_boundary_points(ell, count: int, rng, max_tries: int = 200000) -> np.ndarray:
    """Points theta0 + E z, ||z|| = 1, that the IMI plant can realise: Gamma2z > 0.005, link 2's
    mass (raised if needed, see set_imi_theta) compatible with theta1, friction >= 0."""
    from robust_drake.regressor import IMI_L1

    out = []
    tries = 0
    while len(out) < count and tries < max_tries:
        P = ell.boundary_points(1000, rng)
        tries += 1000
        m2 = np.maximum(4.0, 2.0 * (P[:, 1] ** 2 + P[:, 2] ** 2) / np.maximum(P[:, 3], 1e-9))
        ok = ((P[:, 3] > 0.005) & (P[:, 0] - 0.62 - m2 * IMI_L1 ** 2 > 0.05) & np.all(P[:, 4:] >= 0, axis=1))
        out.extend(P[ok][: count - len(out)])
    if len(out) < count:
        raise RobustDrakeError(f"found only {len(out)} physically realisable points on the ellipsoid boundary")
    return np.array(out)


def settling_time(t, e, band: float) -> float:
    """Last instant at which |e| is above ``band`` (0 if never; nan if still above at the end of the
    log: the response has not settled within the horizon)."""
    above = np.flatnonzero(np.abs(np.asarray(e)) > band)
    if not above.size:
        return 0.0
    return float("nan") if above[-1] == len(t) - 1 else float(t[above[-1]])


def tracking_stats(t, e, settle_tol: float = 0.01, settle_rel: float = 0.1) -> dict:
    """Peak and RMS of |e| per joint and two settling times (s):

    * ``settling_time``: absolute band, the last time |e_j| > ``settle_tol`` (rad);
    * ``settling_time_rel``: relative band around the final error, the last time
      |e_j(t) - e_j(T)| > ``settle_rel`` * max_t |e_j(t) - e_j(T)|, T the end of the log (the classical
      settling time of a step response, applied to the tracking error: both laws leave a steady offset
      under Coulomb friction, of a different size, so a band around zero would time the offset, not
      the transient). This is the definition under which CI section 5.2's "longer settling time" is
      compared: the time the transient takes to decay to ``settle_rel`` of its size. The horizon must
      be long enough for e(T) to be steady.
    """
    e = np.asarray(e, dtype=float)
    a = np.abs(e)
    out = {"peak": a.max(axis=0).tolist(), "rms": np.sqrt(np.mean(e ** 2, axis=0)).tolist()}
    out["settling_time"] = [settling_time(t, a[:, j], settle_tol) for j in range(e.shape[1])]
    d = np.abs(e - e[-1])
    out["settling_time_rel"] = [settling_time(t, d[:, j], settle_rel * d[:, j].max()) for j in range(e.shape[1])]
    out["final_error"] = e[-1].tolist()
    return out


def torque_reconstruction(theta0=None, n_samples: int = 5, seed: int = 0, duration: float = 20.0,
                          points: int = 400) -> dict:
    """CI fig. 3: measured torques (noisy, within CI_BOUNDS) along the exciting trajectory against
    the torques reconstructed with the central estimate, ``D(q, qd, qdd_meas) theta0`` (N m).

    ``theta0`` defaults to the least-squares estimate from the ``n_samples`` D-optimal samples of the
    simulated identification (the SDP's central estimate is within its ellipsoid of it); the published
    section 5.1 theta0 can be passed instead. Returns the dense signals, the n_m identification samples,
    and the RMS reconstruction error per joint against the measured and the noise-free torques.
    """
    from robust_drake.uncertainty.regression import CI_BOUNDS
    from robust_drake.regressor import imi_scara_regressor

    ident = simulate_identification(n_samples, seed, duration=duration)
    if theta0 is None:
        D = imi_scara_regressor(ident["q"], ident["qd"], ident["qdd"]).reshape(-1, 8)
        theta0 = np.linalg.lstsq(D, ident["tau"].reshape(-1), rcond=None)[0]
    theta0 = np.asarray(theta0, dtype=float)
    rng = np.random.default_rng(seed + 1)
    t = np.linspace(0.0, duration, points)
    q, qd, qdd = exciting_trajectory(t)
    tau_true = np.einsum("kij,j->ki", imi_scara_regressor(q, qd, qdd), IMI_THETA_TRUE)
    tau_meas = tau_true + rng.uniform(-1, 1, tau_true.shape) * CI_BOUNDS["tau"]
    qdd_meas = qdd + rng.uniform(-1, 1, qdd.shape) * CI_BOUNDS["qdd"]
    tau_rec = np.einsum("kij,j->ki", imi_scara_regressor(q, qd, qdd_meas), theta0)
    rms = lambda a: np.sqrt(np.mean(a ** 2, axis=0)).tolist()  # noqa: E731
    return {"t": t, "tau_meas": tau_meas, "tau_true": tau_true, "tau_rec": tau_rec, "theta0": theta0.tolist(),
            "t_samples": ident["t"], "tau_samples": ident["tau"],
            "rms_vs_measured": rms(tau_rec - tau_meas), "rms_vs_true": rms(tau_rec - tau_true),
            "rms_noise": rms(tau_meas - tau_true)}


def run_study(theta0=None, P=None, n_true: int = 3, duration: float | None = None, seed: int = 0,
              epsilon: float = 1.0, amplitude=(1.0, 1.0), omega: float = 5.0, rate: float = 1000.0,
              settle_tol: float = 0.01, K=None, Lambda=None, settle_rel: float = 0.1) -> dict:
    """CI section 5.2: nominal vs robust control for ``n_true`` true parameter vectors on the
    boundary of E(P, theta0) (default: the published section 5.1 values).

    ``summary['settling_order_reproduced']``: the paper's "longer settling time" of the robust law,
    judged on ``settling_time_rel`` (see :func:`tracking_stats`): True when the robust law settles
    later than the nominal one on both joints (a joint that has not settled counts as later)."""
    from robust_drake.diagram import ClosedLoopConfig, simulate
    from robust_drake.uncertainty.ellipsoid import Ellipsoid
    from robust_drake.regressor import IMI_P, IMI_THETA0
    from robust_drake.systems.controllers.calafiore_indri import IMI_K, IMI_LAMBDA

    if isinstance(n_true, bool) or not isinstance(n_true, (int, np.integer)) or n_true < 1:
        raise RobustDrakeError(f"n_true must be an integer >= 1 (got {n_true!r}): the study needs at least one "
                               "true parameter vector on the ellipsoid boundary")
    theta0 = IMI_THETA0 if theta0 is None else np.asarray(theta0, dtype=float)
    P = IMI_P if P is None else np.asarray(P, dtype=float)
    ell = Ellipsoid(theta0, P)
    rng = np.random.default_rng(seed)
    trues = physical_boundary_points(ell, n_true, rng)
    if duration is None:
        duration = 1.0 if os.environ.get("ROBUST_DRAKE_SHORT") else 3.0
    runs = []
    agg = {"nominal": [], "robust": []}
    for k, th in enumerate(trues):
        row = {"theta_true": th.tolist(), "radius": float(ell.radius(th))}
        for law in ("nominal", "robust"):
            cfg = ClosedLoopConfig(
                robot="imi_scara", controller="calafiore" if law == "robust" else "calafiore_nominal",
                controller_params={"theta0": theta0, "P": P, "epsilon": epsilon,
                                   "K": IMI_K if K is None else K, "Lambda": IMI_LAMBDA if Lambda is None else Lambda},
                trajectory="step", trajectory_params={"amplitude": list(amplitude), "omega": omega,
                                                      "duration": duration},
                rate=rate, observer="exact", plant_friction={"coulomb": [th[4], th[6]], "viscous": [th[5], th[7]]},
                encoder_resolution=None, torque_limit=None, duration=duration,
                plant_setup=[lambda plant, ctx, th=th: set_imi_theta(plant, ctx, th)],
            )
            res = simulate(cfg)
            e = res.q - res.q_d
            st = tracking_stats(res.t, e, settle_tol, settle_rel)
            st["peak_torque"] = np.abs(res.u).max(axis=0).tolist()
            st["diverged"] = bool(res.diverged)
            row[law] = st
            agg[law].append(st)
            if k == 0:
                row.setdefault("_logs", {})[law] = {"t": res.t, "e": e, "q_d": res.q_d, "u": res.u}
        runs.append(row)
    summary = {}
    for law in ("nominal", "robust"):
        summary[law] = {key: np.mean([s[key] for s in agg[law]], axis=0).tolist()
                        for key in ("peak", "rms", "settling_time", "settling_time_rel", "peak_torque")}
    later = [all((np.isnan(r["robust"]["settling_time_rel"][j]) and not np.isnan(r["nominal"]["settling_time_rel"][j]))
                 or r["robust"]["settling_time_rel"][j] > r["nominal"]["settling_time_rel"][j] for j in range(2))
             for r in runs]
    summary["settling_order_reproduced"] = bool(all(later))
    return {"theta0": theta0.tolist(), "P": P.tolist(), "epsilon": epsilon, "duration": duration,
            "settle_tol": settle_tol, "settle_rel": settle_rel, "runs": runs, "summary": summary}


def study_figures(out: dict) -> dict:
    """Analogs of CI figs. 3-6 of a :func:`run_study` result as matplotlib Figures, by file name:
    torque reconstruction (fig. 3), reference (fig. 4), nominal and robust tracking errors on one
    y-scale (figs. 5-6, so the two laws compare at a glance), and the commanded torques."""
    from robust_drake.plotting import style

    with style():
        return _study_figures(out)


def _study_figures(out):
    """Analogs of CI figs. 3-6: torque reconstruction, reference, nominal and robust tracking
    errors (same y-scale, so the two laws compare at a glance), torques; by file name."""
    import numpy as np

    from robust_drake.plotting import subplots

    rec = out.get("_reconstruction") or torque_reconstruction()
    fig, axes = subplots(2, 1, sharex=True, figsize=(9, 5))
    for j, ax in enumerate(axes):
        ax.plot(rec["t"], rec["tau_meas"][:, j], ".", ms=3, label="measured")
        ax.plot(rec["t"], rec["tau_rec"][:, j], "-", label="reconstructed (theta0)")
        ax.plot(rec["t_samples"], rec["tau_samples"][:, j], "o", mfc="none", label="n_m samples used")
        ax.set(ylabel=f"tau{j + 1} [N m]")
    axes[0].set_title("CI fig. 3: measured vs reconstructed torque (theta0 from 5 samples)")
    axes[1].set(xlabel="t [s]")
    axes[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.align_ylabels(axes)
    fig.tight_layout()
    figures = {"fig3_torque_reconstruction.png": fig}
    logs = out["runs"][0]["_logs"]
    t = logs["nominal"]["t"]
    joints = ["joint 1", "joint 2"]
    legend = dict(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    paths = ["fig4_reference.png", "fig5_nominal_errors.png", "fig6_robust_errors.png", "torques.png"]
    fig, ax = subplots(figsize=(7.5, 3.5))
    ax.plot(t, logs["nominal"]["q_d"], label=joints)
    ax.set(xlabel="t [s]", ylabel="q_d [rad]", title="joint reference (CI fig. 4)")
    ax.grid(alpha=0.3)
    ax.legend(**legend)
    fig.tight_layout()
    figures[paths[0]] = fig
    e_max = max(float(np.max(np.abs(logs[law]["e"]))) for law in ("nominal", "robust")) * 1.05 or 1.0
    for law, num, path in (("nominal", 5, paths[1]), ("robust", 6, paths[2])):
        fig, ax = subplots(figsize=(7.5, 3.5))
        ax.plot(logs[law]["t"], logs[law]["e"], label=joints)
        ax.set(xlabel="t [s]", ylabel="e = q - q_d [rad]", ylim=(-e_max, e_max),
               title=f"tracking errors, {law} control (CI fig. {num}; same scale as fig. {11 - num})")
        ax.grid(alpha=0.3)
        ax.legend(**legend)
        fig.tight_layout()
        figures[path] = fig
    fig, axes = subplots(2, 1, figsize=(7.5, 5), sharex=True)
    for j, ax in enumerate(axes):
        for law, style in (("nominal", "-"), ("robust", "--")):
            ax.plot(logs[law]["t"], np.asarray(logs[law]["u"])[:, j], style, lw=0.9, label=f"{law} law")
        ax.set_ylabel(f"u{j + 1} [N m]")
        ax.grid(alpha=0.3)
    axes[0].legend(**legend)
    axes[0].set_title("commanded torques, first drawn true arm")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    figures[paths[3]] = fig
    return figures
