"""Monte Carlo robustness studies: draw "true" plant parameters, run every controller on each.

Two uncertainty sets:

* ``d2r2``: the load intervals of Jaritz & Spong eq. 93 (0 <= dm2 <= 1.1841 kg,
  0 <= dlc2 <= 0.0694 m, 0 <= dI2 <= 0.109 kg m^2) added to the unloaded link 2 of
  ``models/d2r2.urdf`` and mapped to theta by eq. 14 (:func:`d2r2_theta_from_load`). At the
  maximum corner this reproduces table 9 (0.784, 0.183, 0.135) to the table's rounding. The
  draws are uniform in the box (optionally plus its 8 corners); each becomes
  ``ClosedLoopConfig.true_theta`` (applied by :func:`robust_drake.models.set_d2r2_theta`).
* ``imi_scara``: a confidence ellipsoid E(P, theta0) = {theta : (theta - theta0)^T P^-1
  (theta - theta0) <= 1} of Calafiore & Indri (CI eq. 10; JSON with keys ``theta0`` and ``P``
  as written by :mod:`robust_drake.uncertainty.ellipsoid`). Draws are theta0 + P^(1/2) z
  with z uniform in the unit ball (inside) or on the unit sphere (boundary). theta has CI's 8
  entries (4 inertial, then Coulomb/viscous friction of both joints); a draw that no rigid
  body can realise (e.g. Gamma2z <= m2 |s2|^2) is rejected and counted, never silently
  altered. Accepted draws set the plant's inertias (:func:`set_imi_theta`) and its friction.

:func:`run_montecarlo` runs the draws with :func:`robust_drake.batch.run_batch` (parallel,
resumable Parquet) and :func:`percentile_table` / :func:`boxplot` summarise the task-space
error per controller.
"""

from __future__ import annotations

import functools
import json
import math
import pathlib
from typing import Iterable, Sequence

import numpy as np

from robust_drake.description import describe, packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.scenario import Scenario

__all__ = [
    "d2r2_link_params",
    "d2r2_theta_from_load",
    "draw_d2r2",
    "load_ellipsoid",
    "ellipsoid_radius",
    "sample_ellipsoid",
    "imi_realisable",
    "set_imi_theta",
    "draw_imi",
    "montecarlo_scenarios",
    "run_montecarlo",
    "percentile_table",
    "boxplot",
]


# --------------------------------------------------------------------------- D2R2, JS eq. 93


@functools.lru_cache(maxsize=1)
def d2r2_link_params() -> dict:
    """Unloaded D2R2 link parameters read from ``models/d2r2.urdf``:
    m1, lc1, I1, m2, lc2, I2 (central inertias, axis z) and l1."""
    from robust_drake.models import _joint2_offset, make_plant

    plant = make_plant("d2r2", "none")
    ctx = plant.CreateDefaultContext()
    j1, j2, l1 = _joint2_offset(plant)
    out = {"l1": l1}
    for i, body in ((1, j1.child_body()), (2, j2.child_body())):
        m = body.get_mass(ctx)
        c = body.CalcCenterOfMassInBodyFrame(ctx)
        Izz_origin = body.CalcSpatialInertiaInBodyFrame(ctx).CalcRotationalInertia().CopyToFullMatrix3()[2, 2]
        lc = float(math.hypot(c[0], c[1]))
        out.update({f"m{i}": float(m), f"lc{i}": lc, f"I{i}": float(Izz_origin - m * lc * lc)})
    return out


def d2r2_theta_from_load(dm2, dlc2, dI2, params: dict | None = None) -> np.ndarray:
    """JS eq. 14 for the unloaded link 2 plus the eq. 93 load increments.

    m2 -> m2 + dm2, lc2 -> lc2 + dlc2 (distance of link 2's centre of mass from joint 2),
    I2 -> I2 + dI2 (inertia about that centre of mass). Broadcasts; returns (..., 3).
    """
    from robust_drake.models import d2r2_theta

    p = params or d2r2_link_params()
    return d2r2_theta(p["m1"], p["lc1"], p["I1"], p["m2"] + np.asarray(dm2, float),
                      p["lc2"] + np.asarray(dlc2, float), p["I2"] + np.asarray(dI2, float), p["l1"])


def draw_d2r2(draws: int, seed: int = 0, corners: bool = False):
    """Uniform draws of (dm2, dlc2, dI2) over the eq. 93 box; ``corners`` puts the 8 corners
    first. Returns ``(theta (N, 3), deltas (N, 3))``."""
    from robust_drake.models import D2R2_LOAD_INTERVALS

    if draws < 0:
        raise RobustDrakeError(f"draws must be >= 0 (got {draws})")
    lo = np.array([D2R2_LOAD_INTERVALS[k][0] for k in ("dm2", "dlc2", "dI2")])
    hi = np.array([D2R2_LOAD_INTERVALS[k][1] for k in ("dm2", "dlc2", "dI2")])
    rng = np.random.default_rng(seed)
    parts = []
    if corners:
        bits = np.array([[(i >> b) & 1 for b in range(3)] for i in range(8)], dtype=float)
        parts.append(lo + bits * (hi - lo))
    parts.append(lo + rng.random((draws, 3)) * (hi - lo))
    deltas = np.concatenate(parts, axis=0)
    return d2r2_theta_from_load(deltas[:, 0], deltas[:, 1], deltas[:, 2]), deltas


# --------------------------------------------------------------------------- CI ellipsoid


def load_ellipsoid(path) -> tuple[np.ndarray, np.ndarray]:
    """(theta0, P) from a JSON file with keys ``theta0`` and ``P`` (P symmetric positive
    definite, E(P, theta0) = {theta : (theta - theta0)^T P^-1 (theta - theta0) <= 1})."""
    path = pathlib.Path(path)
    try:
        d = json.loads(path.read_text())
        theta0 = np.asarray(d["theta0"], dtype=float).reshape(-1)
        P = np.asarray(d["P"], dtype=float)
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise RobustDrakeError(
            f"cannot read ellipsoid {path}: {exc} (need JSON keys 'theta0' and 'P')") from None
    m = theta0.size
    if P.shape != (m, m):
        raise RobustDrakeError(f"{path}: P must be {m}x{m} for theta0 of length {m}, got {P.shape}")
    if not __import__("robust_drake.analysis.tolerance", fromlist=["is_symmetric"]).is_symmetric(P):
        raise RobustDrakeError(f"{path}: P is not symmetric")
    if np.linalg.eigvalsh(0.5 * (P + P.T))[0] <= 0:
        raise RobustDrakeError(f"{path}: P is not positive definite")
    return theta0, 0.5 * (P + P.T)


def _sqrtm_psd(P):
    w, V = np.linalg.eigh(P)
    return (V * np.sqrt(np.clip(w, 0, None))) @ V.T


def ellipsoid_radius(theta, theta0, P) -> np.ndarray:
    """sqrt((theta - theta0)^T P^-1 (theta - theta0)): <= 1 inside, = 1 on the boundary."""
    d = np.atleast_2d(np.asarray(theta, float) - theta0)
    return np.sqrt(np.einsum("ij,ij->i", d, np.linalg.solve(P, d.T).T))


def sample_ellipsoid(theta0, P, count: int, rng, boundary_fraction: float = 0.5):
    """``count`` points of E(P, theta0): the first ``round(boundary_fraction * count)`` on the
    boundary, the rest uniform inside (z uniform in the unit ball: direction ~ normal,
    radius ~ U^(1/m)). Returns (count, m)."""
    theta0 = np.asarray(theta0, float)
    m = theta0.size
    z = rng.normal(size=(count, m))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    n_boundary = int(round(boundary_fraction * count))
    r = np.ones(count)
    r[n_boundary:] = rng.random(count - n_boundary) ** (1.0 / m)
    return theta0 + (z * r[:, None]) @ _sqrtm_psd(P).T


def _imi_bodies(plant):
    from robust_drake.models import _joint2_offset

    j1, j2, l1 = _joint2_offset(plant)
    return j1, j2, l1


IMI_L1 = packaged_description("imi_scara").link_lengths[0]  # m, CI section 5 (robots/imi_scara.yaml)


def imi_realisable(theta, m2: float = 4.0, m1: float = 12.0, lc1: float = 0.2, I1c: float = 0.13,
                   l1: float = IMI_L1, min_central: float = 1e-4) -> bool:
    """Can a rigid link 2 (mass >= m2, chosen freely upwards) and a link 1 plus a rotor with
    nonnegative inertia realise CI's inertial theta[0:4]? Needs Gamma2z > |m2 s2|^2 / m2 and
    Gamma1z-part theta[0] - m2 l1^2 - (I1c + m1 lc1^2) >= 0; and, for an 8-entry theta,
    nonnegative Coulomb and viscous coefficients theta[4:8] (friction cannot add energy)."""
    th = np.asarray(theta, float)
    if th.size >= 8 and np.any(th[4:8] < 0):  # friction must dissipate (CI eq. 16)
        return False
    h2 = th[1] ** 2 + th[2] ** 2
    if not th[3] > min_central:
        return False
    m2_eff = max(m2, h2 / (th[3] - min_central)) if h2 > 0 else m2
    rotor = th[0] - m2_eff * l1 * l1 - (I1c + m1 * lc1 * lc1)
    return bool(rotor >= 0.0)


def set_imi_theta(plant, context, theta) -> None:
    """Set the IMI SCARA plant's inertial parameters to CI's theta[0:4] (section 5):
    theta = [Gamma1z + m2 l1^2, m2 s2x, m2 s2y, Gamma2z, ...].

    Link 2 keeps its mass (raised if needed so that its central inertia stays positive), its
    centre of mass becomes (theta[1], theta[2]) / m2 and its inertia about joint 2 theta[3];
    link 1 is unchanged and the joint-1 rotor inertia takes the rest of theta[0]. Raises
    RobustDrakeError when that is impossible (see :func:`imi_realisable`). The friction
    entries theta[4:8] are not plant inertias: pass them as the plant friction block.
    """
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia

    th = np.asarray(theta, float).reshape(-1)
    if th.size < 4:
        raise RobustDrakeError(f"imi theta needs at least 4 entries, got {th.size}")
    j1, j2, l1 = _imi_bodies(plant)
    body1, body2 = j1.child_body(), j2.child_body()
    m1 = body1.get_mass(context)
    c1 = body1.CalcCenterOfMassInBodyFrame(context)
    I1_origin = body1.CalcSpatialInertiaInBodyFrame(context).CalcRotationalInertia().CopyToFullMatrix3()[2, 2]
    m2 = body2.get_mass(context)
    h2 = th[1] ** 2 + th[2] ** 2
    min_central = 1e-4
    if not th[3] > min_central:
        raise RobustDrakeError(f"theta[3] = Gamma2z = {th[3]:.4g} <= 0 is not physically realisable")
    if h2 / m2 >= th[3] - min_central:
        m2 = h2 / (th[3] - min_central) * 1.0001
    s2 = np.array([th[1] / m2, th[2] / m2, 0.0])
    Izz_c = th[3] - m2 * (s2[0] ** 2 + s2[1] ** 2)
    rotor = th[0] - m2 * l1 * l1 - I1_origin
    if rotor < 0:
        raise RobustDrakeError(
            f"theta[0] = {th[0]:.4g} is smaller than link 1's inertia plus m2 l1^2 "
            f"({I1_origin + m2 * l1 * l1:.4g}): not realisable with this link 1")
    body2.SetSpatialInertiaInBodyFrame(
        context, SpatialInertia.MakeFromCentralInertia(m2, s2, RotationalInertia(0.5 * Izz_c, Izz_c, Izz_c)))
    actuators = [plant.get_joint_actuator(i) for i in plant.GetJointActuatorIndices()]
    act1 = next((a for a in actuators if a.joint().index() == j1.index()), None)
    if act1 is None:
        raise RobustDrakeError("IMI SCARA plant has no actuator on joint 1 to carry the rotor inertia")
    gear = act1.gear_ratio(context)
    act1.SetRotorInertia(context, rotor / (gear * gear))
    del m1, c1


def draw_imi(theta0, P, draws: int, seed: int = 0, boundary_fraction: float = 0.5,
             max_tries: int = 200):
    """Physically realisable draws of E(P, theta0) for the IMI SCARA.

    Returns ``(thetas (N, m), radii (N,), rejected)`` where ``rejected`` counts the draws that
    no rigid body could realise (resampled, up to ``max_tries`` rounds)."""
    rng = np.random.default_rng(seed)
    n_boundary = int(round(boundary_fraction * draws))
    want = {"boundary": n_boundary, "inside": draws - n_boundary}
    got = {"boundary": [], "inside": []}
    rejected = 0
    for _ in range(max_tries):
        for kind, frac in (("boundary", 1.0), ("inside", 0.0)):
            need = want[kind] - len(got[kind])
            if need <= 0:
                continue
            pts = sample_ellipsoid(theta0, P, max(256, 64 * need), rng, boundary_fraction=frac)
            for p in pts:
                if len(got[kind]) >= want[kind]:
                    break
                if imi_realisable(p):
                    got[kind].append(p)
                else:
                    rejected += 1
        if all(len(got[k]) >= want[k] for k in want):
            break
    else:
        raise RobustDrakeError(
            f"could not find {draws} physically realisable points in the ellipsoid "
            f"({rejected} rejected); the ellipsoid is mostly outside the realisable set")
    thetas = np.array(got["boundary"] + got["inside"]).reshape(-1, np.size(theta0))
    return thetas, ellipsoid_radius(thetas, np.asarray(theta0, float), P), rejected


# --------------------------------------------------------------------------- scenarios


def montecarlo_scenarios(robot: str, controllers: Sequence[str], thetas,
                         base: dict | None = None, controller_params: dict | None = None,
                         tags: Sequence[dict] | None = None) -> list[Scenario]:
    """One scenario per (controller, draw): the draw is the plant's "true" parameter vector.

    For the D2R2 it is ``true_theta`` (eq. 14); for the IMI SCARA the inertial part goes to
    :func:`set_imi_theta` and entries 4..7 to the plant friction (Coulomb, viscous per joint).
    """
    base = dict(base or {})
    out = []
    thetas = np.atleast_2d(np.asarray(thetas, float))
    for c in controllers:
        for i, th in enumerate(thetas):
            d = dict(base)
            d.update(robot=robot, controller=c, draw=i,
                     controller_params=dict((controller_params or {}).get(c, {})))
            if tags is not None:
                d["tags"] = dict(tags[i])
            if describe(robot).closed_form_regressor == "d2r2":  # JS eq. 14 parameters
                d["true_theta"] = [float(x) for x in th]
            elif describe(robot).closed_form_regressor == "imi_scara":  # CI section 5 parameters
                extra = dict(d.get("extra", {}))
                extra["plant_setup"] = [["robust_drake.montecarlo:set_imi_theta",
                                         {"theta": [float(x) for x in th[:4]]}]]
                if th.size >= 8:
                    extra["plant_friction"] = {"coulomb": [float(th[4]), float(th[6])],
                                               "viscous": [float(th[5]), float(th[7])]}
                d["extra"] = extra
                d["tags"] = {**d.get("tags", {}), "theta": [float(x) for x in th]}
            else:
                raise RobustDrakeError(f"Monte Carlo draws are defined for robots with the JS eq. 14 or CI section 5 "
                                       f"parameters in their description (d2r2, imi_scara), not {robot!r}")
            out.append(Scenario.from_dict(d))
    return out


def run_montecarlo(scenarios: Iterable[Scenario], **batch_kwargs):
    """:func:`robust_drake.batch.run_batch` on the draws (same options; progress labelled
    "montecarlo")."""
    from robust_drake.batch import run_batch

    if batch_kwargs.get("progress", True) is True:
        batch_kwargs["progress"] = "montecarlo"

    return run_batch(list(scenarios), **batch_kwargs)


def percentile_table(df, metric: str = "maxerr_task", percentiles=(50, 90, 95, 99)):
    """Per controller: runs, ok/diverged/failed counts, percentiles and the worst case of
    ``metric`` over the ok runs, and which draw was worst."""
    import pandas as pd

    rows = []
    for ctrl, g in df.groupby("controller", sort=False):
        ok = g[g["status"] == "ok"]
        vals = ok[metric].astype(float).to_numpy()
        rec = {"controller": ctrl, "runs": len(g), "ok": len(ok),
               "diverged": int((g["status"] == "diverged").sum()),
               "failed": int((g["status"] == "failed").sum())}
        for p in percentiles:
            rec[f"p{p}"] = float(np.percentile(vals, p)) if len(vals) else math.nan
        if len(vals):
            worst = ok.iloc[int(np.nanargmax(vals))]
            rec.update(worst=float(vals.max()), worst_draw=int(worst["draw"]),
                       worst_theta=(None if worst.get("true_theta") is None
                                    else [float(x) for x in worst["true_theta"]]))
        else:
            rec.update(worst=math.nan, worst_draw=-1, worst_theta=None)
        rows.append(rec)
    return pd.DataFrame(rows)


def boxplot(df, path, metric: str = "maxerr_task", title: str | None = None,
            also: Sequence[str] = ("error_task",)) -> None:
    """Box plots per controller (ok runs) of ``metric`` and of the ``also`` metrics, one panel
    each, worst case marked with a red triangle, controllers by their paper names (LG+, SP1); on a
    log axis when the controllers' medians differ by more than a factor 5 (ZC's spread would
    flatten the others on a linear one: medians a factor 5 apart or interquartile ranges a factor 10
    apart); the diverged and failed runs are counted under each box.
    Saved to ``path``."""
    from robust_drake.plotting import style, subplots
    from robust_drake.registry import paper_name

    metrics = [metric] + [m for m in also if m != metric and m in df.columns]
    ctrls = list(dict.fromkeys(df["controller"]))
    with style():
        fig, axes = subplots(2, len(metrics), squeeze=False, sharex="col", height_ratios=(3, 2),
                             figsize=(0.8 + (1.6 + 1.0 * max(1, len(ctrls))) * len(metrics), 6.6))
        for ax, rel, m in zip(axes[0], axes[1], metrics):
            groups = [df[(df["controller"] == c) & (df["status"] == "ok")][m].astype(float).dropna()
                      .to_numpy() for c in ctrls]
            ax.boxplot([v if len(v) else np.array([np.nan]) for v in groups], whis=(5, 95))
            labels = []
            for c, v in zip(ctrls, groups):
                bad = int(((df["controller"] == c) & (df["status"] != "ok")).sum())
                labels.append(paper_name(c) + (f"\n({bad} not ok)" if bad else ""))
            ax.set_xticks(range(1, len(ctrls) + 1), labels)
            marked = False
            for i, v in enumerate(groups, start=1):
                if len(v):
                    ax.plot([i], [v.max()], "rv", ms=7, label=None if marked else "worst draw")
                    marked = True
            # one controller's spread (ZC's) or level flattening the others' boxes: a log axis
            ok = [v for v in groups if len(v)]
            iqr = [float(np.subtract(*np.percentile(v, [75, 25]))) for v in ok]
            med = [float(np.median(v)) for v in ok]
            positive = all(np.min(v) > 0 for v in ok)
            if positive and len(ok) > 1 and (max(med) > 5 * min(med)
                                             or max(iqr) > 10 * max(min(iqr), 1e-300)):
                ax.set_yscale("log")
            unit = "m" if m.endswith("task") else "rad"
            ax.set_ylabel(f"{m} [{unit}]" + (" (log scale)" if ax.get_yscale() == "log" else ""))
            ax.grid(True, axis="y", which="both", alpha=0.3)
            ax.set_title(f"{m} (box 25-75 %, whiskers 5-95 %)", fontsize=9.5)
            # each controller's spread on one scale: the draws relative to its own median
            rel.boxplot([100.0 * (v / np.median(v) - 1.0) if len(v) and np.median(v) != 0 else np.array([np.nan])
                         for v in groups], whis=(5, 95))
            rel.axhline(0.0, color="0.5", lw=0.8)
            rel.set_xticks(range(1, len(ctrls) + 1), labels)
            rel.set_ylabel("vs own median [%]")
            rel.grid(True, axis="y", alpha=0.3)
        if axes[0][-1].get_legend_handles_labels()[0]:
            axes[0][-1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
        fig.suptitle(title or "Monte Carlo per controller (whiskers 5-95 %, red = worst draw)")
        fig.tight_layout()
    pathlib.Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
