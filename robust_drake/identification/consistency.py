"""Physically consistent identification: one pseudo-inertia LMI per link, posed with Drake.

Standard parameters of link i (about its body origin, in its body frame)::

    pi_i = [m, h_x, h_y, h_z, I_xx, I_yy, I_zz, I_xy, I_xz, I_yz],   h = m c

are physically consistent iff the pseudo-inertia (Wensing, Kim & Slotine 2017)::

    J_i = [[ tr(I)/2 * 1 - I ,  h ],
           [        h^T      ,  m ]]   >= 0      (4 x 4 LMI, linear in pi_i)

Inverse dynamics (with gravity) is linear in all pi_i: tau = Y_std(q, qd, qdd) pi. The base
parameters of the Drake-derived regressor are a linear map of them, theta_base = K pi
(``InverseDynamicsRegressor.K``; reflected rotor inertias of the URDF's transmissions are extra
standard parameters, constrained >= 0).

The data enter only through the compressed normal equations: A = [Y_base | Y_extra] weighted,
A = Q R, z = Q^T b, so the SDP sees a p x p triangle instead of N n rows.

Two programs, both solved with ``MathematicalProgram`` (Clarabel/SCS, whichever Drake picks) and
checked afterwards (eigenvalues of every J_i):

1. **Nearest feasible point** (:func:`consistent_fit`)::

       min_{pi, c}  || R [K pi; c] - z ||^2 + lambda || pi - pi_prior ||^2
       s.t.         J_i(pi_i) >= 0, m_i >= m_min          for every link i

   with a tiny ``lambda`` (``PRIOR_WEIGHT``). Its misfit S_0 is the smallest misfit a physically
   consistent body reaches. Seen on a real current-based 6-axis arm (issue 21): an upper arm of
   82 kg (CAD 12.9 kg), so the feasible point nearest the least-squares estimate need not be
   a plausible one.

2. **Regularised toward the URDF** (:func:`regularised_fit`), the log-det (Bregman, entropic)
   divergence of Lee, Wensing & Park 2020 (IEEE T-RO, "Geometric robot dynamic identification: a
   convex programming approach")::

       d(J || J0) = -log det(J0^-1 J) + tr(J0^-1 J) - 4     (convex in J, 0 iff J = J0)

   posed with Drake's ``AddMaximizeLogDeterminantCost`` (exponential + PSD cones) on the whitened
   matrix  L0^-1 J L0^-T  (J0 = L0 L0^T), which is unit-free (affine invariant). A reflected rotor
   inertia the URDF declares (``Ia_j``, prior a0 > 0) gets the 1 x 1 form -log(a/a0) + a/a0 - 1.
   Penalised form ``min S(x) + gamma sum_i d_i``; solved in its equivalent constrained form::

       min  sum_i d(J_i || J0_i)   s.t.  S(x) <= S_0 + Delta,   Delta = c s^2 chi2_{r}(level)

   (gamma is the inverse Lagrange multiplier of the misfit bound). Rule for Delta: the misfit may
   grow over the regularisation-free S_0 by at most its own chi-square spread: for any fixed x the
   misfit increase over the least-squares optimum is (x - x_hat)^T A^T A (x - x_hat), distributed
   c s^2 chi2_r for the true x, with r = rank of R (identifiable directions), s^2 = RSS_LS /
   (rows - r) the weighted residual variance and c the residual's integrated correlation time in
   samples (:func:`integrated_correlation`: correlated rows carry fewer degrees of freedom, 1 for
   white noise); level ``LEVEL`` (0.95, as ``model_repair.decisions``). When S_0 + Delta is not
   binding the estimate is the URDF's own body (the data cannot tell it from the URDF).

Priors J0: the URDF's inertials. A link whose J0 is singular (a massless frame, a point mass) gets
J0 + ``PRIOR_FLOOR`` x the pseudo-inertia of a uniform cube of half-size its extent and mass the
median of the other links' masses (its neighbours' scale; for a link with a URDF mass, its own mass and
only the second-moment block); said in ``regularisation.notes``.

Rotor inertias before link inertias (issue 21, item 3): on a geared joint (actuator gear ratio > 1
in the URDF, or ``gear_ratio`` > 1 in the description) whose regressor has no ``Ia_<joint>``, a
reflected-inertia column qdd_j is added as a candidate (:func:`rotor_candidates`), >= 0, bounded
above by ``PLAUSIBLE_RATIO`` x G^2 I_r when the description gives the rotor inertia I_r. It enters
no divergence, so the regularised fit puts inertia the data need on that joint's diagonal into it
before it moves a link away from the URDF (on the first joint of an arm with a vertical first axis
it shares one data direction with link 1's I_zz: only the prior tells them apart).

With instruments (the repair's IV estimator) R is the factor of the projected problem [P_Z A | b]
and s^2 its residual variance: larger than the least-squares one by the part of the columns the
instruments do not explain, so the allowance errs on the side of the prior there.

Measured (``robust-drake repair`` of DFKI C.1, the files of tests/test_repair_dfki.py, IV estimator):
the nearest feasible point had link 2 at 0.513 kg (URDF 0.626 kg) with its COM at 0.298 m (the
end of its 0.3 m geometry, URDF 0.256 m) and Ia_joint2 0.00298 kg m^2 (URDF 0.00226); regularised
(budget binding, c = 34, r = 12): link 2 0.623 kg, COM 0.250 m, Ia_joint2 0.00228, link 1 0.436 kg
(URDF 0.523), COM 0.186 m (URDF 0.200); the consistent model's validation RMS torque 0.1043 /
0.0877 -> 0.1062 / 0.0791 N m, replay RMS q of the repaired model 0.0176 / 0.0341 -> 0.0150 /
0.0300 rad. Simulated serial7 (URDF = truth, 0.1 rad excitation, 0.3 N m noise, 15 s at 250 Hz):
masses 4, 4, 3, 2.7, 1.7, 1.8, 0.3 kg; nearest feasible 4, 4, 3.25, 2.86, 1.42, 1.89, 0.28;
regularised 4, 4, 3.00, 2.70, 1.70, 1.80, 0.30 (budget not binding: the URDF fits within it).

Plausibility (:func:`plausibility_report`): per link, mass vs the URDF's (off by more than
``PLAUSIBLE_RATIO`` either way), centre of mass outside the link's extent (:func:`link_extents`),
central principal moments negative or with a radius of gyration beyond the extent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from robust_drake.errors import RobustDrakeError, SolverError

PRIOR_WEIGHT = 1e-6  # lambda relative to trace(R^T R) / p
M_MIN = 1e-4  # kg
#: confidence level of the misfit allowance (as ``model_repair.decisions.LEVEL``)
LEVEL = 0.95
#: a fitted mass (or rotor inertia bound) off the prior by more than this factor either way is implausible
PLAUSIBLE_RATIO = 3.0
#: weight of the cube pseudo-inertia added to a singular prior J0 (massless frame, point mass)
PRIOR_FLOOR = 1e-2
#: constrained form: + TIE_BREAK x misfit / budget in the objective (changes sum d by at most this)
TIE_BREAK = 1e-3


def _spatial_inertia(pi):
    from pydrake.multibody.tree import SpatialInertia, UnitInertia

    m = pi[0]
    c = pi[1:4] / m
    I = pi[4:10] / m
    return SpatialInertia(m, c, UnitInertia(I[0], I[1], I[2], I[3], I[4], I[5]), skip_validity_check=True)


def pseudo_inertia(pi) -> np.ndarray:
    """J(pi) of one link (Wensing et al. 2017, eq. 9 form), linear in pi."""
    m, h, (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) = pi[0], np.asarray(pi[1:4]), pi[4:10]
    I = np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]])
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(I) * np.eye(3) - I
    J[:3, 3] = h
    J[3, :3] = h
    J[3, 3] = m
    return J


def bregman_logdet(J: np.ndarray, J0: np.ndarray) -> float:
    """d(J || J0) = -log det(J0^-1 J) + tr(J0^-1 J) - dim (Lee, Wensing & Park 2020); inf if J is not PD."""
    L = np.linalg.cholesky(J0)
    Jh = np.linalg.solve(L, np.linalg.solve(L, J).T)
    sign, logdet = np.linalg.slogdet(0.5 * (Jh + Jh.T))
    return float(-logdet + np.trace(Jh) - len(J)) if sign > 0 else math.inf


def _cube(m: float, a: float) -> np.ndarray:
    """Pseudo-inertia of a uniform cube of mass m [kg], half-size a [m], centred at the origin:
    the second moment of mass is m a^2 / 3 per axis."""
    return np.diag([m * a * a / 3.0] * 3 + [m])


def prior_pseudo_inertias(links_prior: np.ndarray, extents) -> tuple[list[np.ndarray], list[int]]:
    """J0_i of the URDF's links (nb, 10); a singular J0 (min eigenvalue <= 1e-9 x its largest, or a
    massless link) gets + PRIOR_FLOOR x _cube(m_ref, extent) with m_ref its own mass or, massless,
    the median of the other links' masses (then only the second-moment block when the link has a
    URDF mass). Returns (J0 list, indices of the links whose prior was floored)."""
    masses = np.asarray(links_prior[:, 0], float)
    J0s, changed = [], []
    for i, p in enumerate(links_prior):
        J0 = pseudo_inertia(p)
        w = np.linalg.eigvalsh(J0)
        if p[0] > 0 and w.min() > 1e-9 * max(w.max(), 1e-300):
            J0s.append(J0)
            continue
        others = masses[(masses > 0) & (np.arange(len(masses)) != i)]
        m_ref = p[0] if p[0] > 0 else (float(np.median(others)) if len(others) else 1.0)
        floor = PRIOR_FLOOR * _cube(m_ref, float(extents[i]))
        if p[0] > 0:  # only the second moment is singular: the URDF's mass stays the prior's
            floor[3, 3] = 0.0
        J0s.append(J0 + floor)
        changed.append(i)
    return J0s, changed


def integrated_correlation(residual: np.ndarray, segment: np.ndarray | None = None) -> float:
    """c = 1 + 2 sum_k rho_k [samples]: the integrated autocorrelation time of a residual (N, n),
    autocorrelation pooled over the gap-free segments, summed up to the first lag where it is <= 0
    (initial positive sequence); the largest over the joints, at least 1 (white noise: 1)."""
    from robust_drake.identification.data import pooled_autocorrelation

    rho = pooled_autocorrelation(residual, segment)
    max_lag = rho.shape[0]
    best = 1.0
    for j in range(rho.shape[1]):
        neg = np.nonzero(rho[1:, j] <= 0)[0]
        stop = int(neg[0]) + 1 if len(neg) else max_lag
        best = max(best, 1.0 + 2.0 * float(np.sum(rho[1:stop, j])))
    return best


def misfit_allowance(rss: float, rows: int, rank: int, inflation: float = 1.0, level: float = LEVEL) -> dict:
    """Delta = c s^2 chi2_{rank}(level), s^2 = rss / (rows - rank): how far the misfit may rise
    above its regularisation-free value (module docstring). Units: those of rss (weighted N^2 m^2)."""
    from scipy.stats import chi2

    dof = max(int(rows) - int(rank), 1)
    s2 = float(rss) / dof
    q = float(chi2.ppf(level, max(int(rank), 1)))
    return {"sigma2": s2, "inflation": float(inflation), "chi2_quantile": q, "rank": int(rank), "rows": int(rows),
            "level": float(level), "allowance": float(inflation) * s2 * q}


def _compress(A, b, R_full):
    """(R, z, rss) of [A | b]: ||A x - b||^2 = ||R x - z||^2 + rss."""
    if R_full is None:
        R_full = np.linalg.qr(np.column_stack([A, b]), mode="r")
    p = R_full.shape[1] - 1
    rss = float(R_full[p, p] ** 2) if R_full.shape[0] > p else 0.0
    return R_full[:p, :p], R_full[:p, p], rss


def _program(R, K, n_links, n_extra, c_lower=None, c_upper=None):
    """MathematicalProgram with pi (p_std), c (n_extra), one pseudo-inertia LMI per link, the
    URDF extras >= 0 and bounds on c; returns (prog, pi, c, RM) with theta = M x, x = [pi; c]."""
    from pydrake.solvers import MathematicalProgram

    p_base, p_std = K.shape
    p = R.shape[0]
    prog = MathematicalProgram()
    pi = prog.NewContinuousVariables(p_std, "pi")
    c = prog.NewContinuousVariables(n_extra, "c") if n_extra else np.zeros(0, dtype=object)
    M = np.zeros((p, p_std + n_extra))
    M[:p_base, :p_std] = K
    M[p_base:, p_std:] = np.eye(n_extra)
    F = [_J_coeff(k) for k in range(10)]
    for i in range(n_links):
        prog.AddLinearMatrixInequalityConstraint([np.zeros((4, 4))] + F, pi[10 * i:10 * i + 10])
    for k in range(10 * n_links, p_std):
        prog.AddBoundingBoxConstraint(0.0, np.inf, pi[k])
    lo = np.full(n_extra, -np.inf) if c_lower is None else np.asarray(c_lower, float)
    hi = np.full(n_extra, np.inf) if c_upper is None else np.asarray(c_upper, float)
    for k in np.nonzero(np.isfinite(lo) | np.isfinite(hi))[0]:
        prog.AddBoundingBoxConstraint(lo[k], hi[k], c[k])
    return prog, pi, c, R @ M


def _solve(prog, what):
    from pydrake.solvers import Solve

    from robust_drake.log import debug_solve

    result = Solve(prog)
    debug_solve(what, result)
    name = result.get_solver_id().name()
    if not result.is_success():
        raise SolverError(f"{what} failed ({name}: {result.get_solution_result()})")
    return result, name


def consistent_fit(A: np.ndarray | None, b: np.ndarray | None, K: np.ndarray, pi_prior: np.ndarray, n_links: int,
                   n_extra: int, prior_weight: float = PRIOR_WEIGHT, m_min: float = M_MIN,
                   R_full: np.ndarray | None = None, c_lower=None, c_upper=None):
    """Nearest feasible point (program 1 of the module docstring). A: (rows, p_base + n_extra)
    weighted regressor, b: rows.

    ``pi`` = [10 per link | non-negative extras (reflected inertia, damping)], theta_base = K pi.
    ``R_full``: the R factor of [A | b] already computed (``ColumnCache.qr_r``, by row blocks);
    then A and b are not used. ``c_lower``/``c_upper``: bounds on the extra coefficients.
    Returns (pi (p_std,), extra coefficients (n_extra,), solver name)."""
    R, z, _ = _compress(A, b, R_full)
    p = R.shape[0]
    p_std = K.shape[1]
    prog, pi, c, RM = _program(R, K, n_links, n_extra, c_lower, c_upper)
    lam = prior_weight * max(np.trace(R.T @ R) / p, 1e-12)
    # normalise the prior term per parameter by its own size (masses ~1, inertias ~1e-2)
    pscale = np.maximum(np.abs(pi_prior), 1e-3 * max(np.abs(pi_prior).max(), 1e-9))
    t = prog.NewContinuousVariables(1, "t")[0]
    x = np.concatenate([pi, c])
    rows_A = np.vstack([RM, np.sqrt(lam) * np.hstack([np.diag(1.0 / pscale), np.zeros((p_std, n_extra))])])
    rows_b = np.concatenate([z, np.sqrt(lam) * pi_prior / pscale])
    Acone = np.zeros((1 + rows_A.shape[0], 1 + len(x)))
    Acone[0, 0] = 1.0
    Acone[1:, 1:] = rows_A
    prog.AddLorentzConeConstraint(Acone, np.concatenate([[0.0], -rows_b]), np.concatenate([[t], x]))
    prog.AddLinearCost(np.array([1.0]), [t])
    for i in range(n_links):
        if pi_prior[10 * i] > 0:
            prog.AddBoundingBoxConstraint(m_min, np.inf, pi[10 * i])
    result, name = _solve(prog, "physically consistent fit (pseudo-inertia LMIs)")
    cs = result.GetSolution(c) if n_extra else np.zeros(0)
    return result.GetSolution(pi), cs, name


def _J_coeff(k: int) -> np.ndarray:
    e = np.zeros(10)
    e[k] = 1.0
    return pseudo_inertia(e)


def _add_divergence(prog, v, J0, weight: float) -> None:
    """+ weight * (-log det(L^-1 J(v) L^-T) + tr(L^-1 J(v) L^-T)) for J0 = L L^T (the constant
    log det J0 - dim dropped); J(v) linear in the 10 variables ``v`` (or 1 for a 1 x 1 prior)."""
    if np.ndim(J0) == 0:  # scalar prior a0 > 0: J(v) = v / a0
        G = [np.array([[1.0 / float(J0)]])]
    else:
        Li = np.linalg.inv(np.linalg.cholesky(J0))
        G = [Li @ _J_coeff(k) @ Li.T for k in range(10)]
    from pydrake.symbolic import Expression

    Gs = np.array(G)  # (k, d, d) numeric: each entry of J(v) is sum_k G[k, r, s] v_k (no numpy object ufuncs)

    def entry(r, s):
        e = Expression(0.0)
        for k in np.nonzero(Gs[:, r, s])[0]:
            e = e + float(Gs[k, r, s]) * v[k]
        return e

    Jh = np.array([[entry(r, s) for s in range(Gs.shape[2])] for r in range(Gs.shape[1])], dtype=object)
    cost, _, _ = prog.AddMaximizeLogDeterminantCost(Jh)
    cost.evaluator().UpdateCoefficients(weight * cost.evaluator().a())
    prog.AddLinearCost(weight * np.array([np.trace(g) for g in G]), v[:len(G)])


def regularised_fit(R_full, K, J0s, n_links: int, n_extra: int, *, budget: float | None = None,
                    gamma: float | None = None, ia_prior=None, c_lower=None, c_upper=None) -> dict:
    """Program 2 of the module docstring on the compressed data (R_full of [A | b]).

    ``budget``: constrained form, min sum d_i + TIE_BREAK S / budget s.t. S = ||R x - z||^2 <= budget
    (the compressed misfit, without the least-squares RSS); else ``gamma``: penalised form min ||R x - z||^2 + gamma sum d_i.
    J0s: the links' prior pseudo-inertias; ``ia_prior`` (p_std - 10 n_links,): priors a0 of the
    URDF extras (> 0: 1 x 1 divergence; else only >= 0). Returns {"pi", "c", "solver", "misfit",
    "divergence" (per link and extra, value of d at the solution)}."""
    R, z, _ = _compress(None, None, R_full)
    if (budget is None) == (gamma is None):
        raise RobustDrakeError("regularised_fit: give exactly one of budget and gamma")
    prog, pi, c, RM = _program(R, K, n_links, n_extra, c_lower, c_upper)
    x = np.concatenate([pi, c])
    w = 1.0 if budget is not None else float(gamma)
    for i in range(n_links):
        _add_divergence(prog, pi[10 * i:10 * i + 10], J0s[i], w)
    ia = np.zeros(K.shape[1] - 10 * n_links) if ia_prior is None else np.asarray(ia_prior, float)
    for k, a0 in enumerate(ia):
        if a0 > 0:
            _add_divergence(prog, pi[10 * n_links + k:10 * n_links + k + 1], a0, w)
    # rotated Lorentz cone s * 1 >= ||r||^2, r = RM x - z; constrained form: s <= budget and a
    # tie-break TIE_BREAK * s / budget (without it the extras are not unique while the bound is slack)
    s = prog.NewContinuousVariables(1, "s")
    A = np.zeros((2 + len(z), 1 + len(x)))
    A[0, 0] = 1.0
    A[2:, 1:] = RM
    prog.AddRotatedLorentzConeConstraint(A, np.concatenate([[0.0, 1.0], -z]), np.concatenate([s, x]))
    if budget is not None:
        prog.AddBoundingBoxConstraint(0.0, float(budget), s)
    prog.AddLinearCost(np.array([1.0 if budget is None else TIE_BREAK / max(float(budget), 1e-300)]), s)
    result, name = _solve(prog, "regularised consistent fit (log-det divergence to the URDF)")
    pis = result.GetSolution(pi)
    cs = result.GetSolution(c) if n_extra else np.zeros(0)
    r = RM @ np.concatenate([pis, cs]) - z
    div = [bregman_logdet(pseudo_inertia(pis[10 * i:10 * i + 10]), J0s[i]) for i in range(n_links)]
    div += [float(-math.log(max(pis[10 * n_links + k] / a0, 1e-300)) + pis[10 * n_links + k] / a0 - 1.0)
            for k, a0 in enumerate(ia) if a0 > 0]
    return {"pi": pis, "c": cs, "solver": name, "misfit": float(r @ r), "divergence": div}


@dataclass(frozen=True)
class RotorCandidate:
    """A reflected rotor inertia offered to the consistent fit on a geared joint the regressor has
    no ``Ia_<joint>`` for: column qdd_j (``robust_drake.effects.RotorInertia``), 0 <= Ia <= ``upper``."""

    joint: int  # velocity index
    name: str  # joint name
    gear_ratio: float
    upper: float  # kg m^2; PLAUSIBLE_RATIO x G^2 x the description's rotor inertia, inf without one
    prior: float | None  # G^2 x the description's rotor inertia [kg m^2], None when not given


def rotor_candidates(regressor, robot, effects=()) -> list[RotorCandidate]:
    """Geared joints (actuator gear ratio > 1, else the description's ``gear_ratio`` > 1) without a
    reflected inertia in the regressor (``Ia_<joint>``) or among ``effects`` (a rotor_inertia effect)."""
    from robust_drake.description import describe

    plant = getattr(regressor, "plant", None)
    if plant is None:
        return []
    try:
        desc = describe(robot)
    except RobustDrakeError:
        desc = None
    Ir = getattr(desc, "rotor_inertia", None)
    G_desc = getattr(desc, "gear_ratio", None) or 1.0
    taken = {e.joint for e in effects if getattr(e, "kind", "") == "rotor_inertia"}
    names = set(regressor.standard_names)
    out = []
    for ai in plant.GetJointActuatorIndices():
        act = plant.get_joint_actuator(ai)
        joint = act.joint()
        if joint.num_velocities() != 1 or f"Ia_{joint.name()}" in names:
            continue
        j = int(joint.velocity_start())
        if None in taken or j in taken:
            continue
        G = float(act.default_gear_ratio())
        G = G if G > 1.0 else float(G_desc)
        if G <= 1.0:
            continue
        prior = G * G * float(Ir) if Ir else None
        out.append(RotorCandidate(j, joint.name(), G, PLAUSIBLE_RATIO * prior if prior else math.inf, prior))
    return sorted(out, key=lambda r: r.joint)


def _geometry_radius(urdf: str, link: str) -> float | None:
    """Radius [m] about the link origin of the ball holding the URDF's box/cylinder/sphere
    visuals and collisions of ``link`` (meshes have no size here); None without any."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(urdf).getroot()
    except (OSError, ET.ParseError):
        return None
    best = None
    for el in root.iter("link"):
        if el.get("name") != link:
            continue
        for part in list(el.iter("visual")) + list(el.iter("collision")):
            o = part.find("origin")
            xyz = np.array([float(s) for s in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()])
            g = part.find("geometry")
            half = None
            for shape in (list(g) if g is not None else []):
                if shape.tag == "box":
                    half = 0.5 * float(np.linalg.norm([float(s) for s in shape.get("size", "0 0 0").split()]))
                elif shape.tag == "cylinder":
                    half = math.hypot(float(shape.get("radius", 0)), 0.5 * float(shape.get("length", 0)))
                elif shape.tag == "sphere":
                    half = float(shape.get("radius", 0))
            if half is not None:
                best = max(best or 0.0, float(np.linalg.norm(xyz)) + half)
    return best


def link_extents(regressor, body_names, links_prior) -> tuple[list[float], list[str]]:
    """Extent [m] of every link: the radius about its origin of a ball holding its URDF geometry
    (box/cylinder/sphere), the origins of its child joints (distance to the next joint) and the
    URDF's own body (its COM distance and radius of gyration: the URDF's body is inside its
    extent), whichever exist ("geometry", "next joint"); a link with neither geometry nor child
    joints: 2 x the larger of its URDF COM distance and radius of gyration ("URDF body x 2"), or,
    massless, the median of the other links' extents ("other links"). Returns (extents, sources)."""
    plant = regressor.plant
    urdf = str(getattr(regressor, "urdf", "") or "")
    ext, src = [], []
    for name, p in zip(body_names, links_prior):
        body = plant.GetBodyByName(name)
        com = float(np.linalg.norm(p[1:4] / p[0])) if p[0] > 0 else 0.0
        if p[0] > 0:  # the URDF's own body is inside its extent: COM and radius of gyration
            com = max(com, math.sqrt(max(_central(p)[1].max(), 0.0) / p[0]))
        geo = _geometry_radius(urdf, name) if urdf.endswith(".urdf") else None
        kids = [float(np.linalg.norm(plant.get_joint(ji).frame_on_parent().GetFixedPoseInBodyFrame().translation()))
                for ji in plant.GetJointIndices() if plant.get_joint(ji).parent_body().index() == body.index()]
        parts = [("geometry", geo)] if geo else []
        parts += [("next joint", max(kids))] if kids and max(kids) > 0 else []
        if parts:
            ext.append(max([v for _, v in parts] + [com]))
            src.append(" + ".join(s for s, _ in parts))
        elif com > 0:
            ext.append(2.0 * com)
            src.append("URDF body x 2")
        else:
            ext.append(math.nan)
            src.append("other links")
    known = [e for e in ext if np.isfinite(e)]
    fill = float(np.median(known)) if known else 0.1
    return [e if np.isfinite(e) else fill for e in ext], src


def _central(p):
    """(c [m], central principal moments [kg m^2]) of one link's standard parameters."""
    m = p[0]
    c = p[1:4] / m if m > 0 else np.zeros(3)
    Ixx, Iyy, Izz, Ixy, Ixz, Iyz = p[4:10]
    I_o = np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]])
    I_c = I_o - m * (np.dot(c, c) * np.eye(3) - np.outer(c, c))
    return c, np.linalg.eigvalsh(0.5 * (I_c + I_c.T))


def plausibility_report(pi, pi_prior, link_names, extents, ratio: float = PLAUSIBLE_RATIO) -> list[dict]:
    """Per link (pi, pi_prior: (nb, 10) standard parameters, extents [m]): mass vs the URDF's (off
    by more than ``ratio`` either way; not judged for a massless URDF link), centre of mass outside
    the extent, central principal moments < 0 (beyond 1e-9 of the largest) or a radius of
    gyration sqrt(I_max / m) beyond the extent (no body inside a ball of radius e has one).
    Returns one dict per link with ``plausible`` and a one-line ``warning`` (None when plausible)."""
    out = []
    for name, p, p0, ext in zip(link_names, np.asarray(pi, float), np.asarray(pi_prior, float), extents):
        m, m0 = float(p[0]), float(p0[0])
        c, mom = _central(p)
        d = float(np.linalg.norm(c))
        rog = math.sqrt(max(mom.max(), 0.0) / m) if m > 0 else math.inf
        issues = []
        k = m / m0 if m0 > 0 and m > 0 else None
        if m0 > 0 and (m <= 0 or k > ratio or k < 1.0 / ratio):
            issues.append(f"mass {m:.3g} kg vs URDF {m0:.3g} kg ({k:.2g}x)" if m > 0 else f"mass {m:.3g} kg")
        if d > ext:
            issues.append(f"COM {d:.3g} m from the link origin, outside its extent {ext:.3g} m")
        if mom.min() < -1e-9 * max(abs(mom).max(), 1e-300):
            issues.append(f"negative principal moment {mom.min():.3g} kg m^2")
        elif rog > ext:
            issues.append(f"radius of gyration {rog:.3g} m beyond its extent {ext:.3g} m")
        out.append({"link": str(name), "mass": m, "mass_urdf": m0, "mass_ratio": k, "com_distance": d,
                    "extent": float(ext), "principal_moments": [float(x) for x in mom],
                    "radius_of_gyration": rog if math.isfinite(rog) else None,
                    "plausible": not issues, "warning": f"link {name}: " + "; ".join(issues) if issues else None})
    return out


def _bodies(names, links) -> dict:
    return {b: {"mass": float(p[0]), "com": (p[1:4] / p[0]).tolist(), "inertia_origin": p[4:10].tolist()}
            for b, p in zip(names, links)}


@dataclass
class ConsistentResult:
    theta: np.ndarray  # full parameter vector [theta_base (consistent) | extra coefs]
    pi: np.ndarray  # (nb, 10) standard parameters per link (the regularised estimate when it ran)
    body_names: list[str]
    min_eig: list[float]  # smallest eigenvalue of every J_i (>= -tol)
    solver: str
    #: reflected inertias / damping of the URDF's transmissions, and the rotor candidates' Ia_<joint>
    #: (the replay's plant gets both: ``set_plant_inertias``)
    extras: dict | None = None
    #: (nb, 10) the nearest feasible point (program 1), before the regularisation
    nearest_pi: np.ndarray | None = None
    nearest_extras: dict | None = None  # the URDF extras (Ia_, b_) of the nearest feasible point
    regularisation: dict = field(default_factory=dict)
    plausibility: list = field(default_factory=list)
    #: rotor candidates: their coefficients (column order of ``rotor``) and the candidates
    rotor_theta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rotor: list = field(default_factory=list)
    #: the rotor candidates' effects (``RotorInertia``, set by ``model_repair.stages``), for predictions
    rotor_effects: list = field(default_factory=list, repr=False)

    @property
    def implausible(self) -> list[str]:
        """Names of the links whose body failed the plausibility check."""
        return [r["link"] for r in self.plausibility if not r["plausible"]]

    def as_dict(self):
        # the rotor candidates are listed under "rotor_candidates", not "extras": the identified
        # model's base values (theta_base = K pi) do not hold them, and the export writes "extras"
        # into the URDF (identification.export), which must stay the model's own arm
        cand = {f"Ia_{r.name}" for r in self.rotor}
        d = {"bodies": _bodies(self.body_names, self.pi),
             "min_pseudo_inertia_eig": [float(x) for x in self.min_eig], "solver": self.solver,
             "extras": {k: v for k, v in (self.extras or {}).items() if k not in cand}}
        if self.nearest_pi is not None:
            d["nearest_feasible_bodies"] = _bodies(self.body_names, self.nearest_pi)
        d["regularisation"] = self.regularisation
        d["plausibility"] = self.plausibility
        d["rotor_candidates"] = [{"joint": r.joint, "name": r.name, "gear_ratio": r.gear_ratio,
                                  "upper": None if not math.isfinite(r.upper) else r.upper, "prior": r.prior,
                                  "reflected_inertia": float(v)} for r, v in zip(self.rotor, self.rotor_theta)]
        return d


def _rank(R: np.ndarray) -> int:
    """Numerical rank of R with unit-norm columns, singular values > RANK_TOL x the largest."""
    from robust_drake.identification.least_squares import RANK_TOL

    norms = np.linalg.norm(R, axis=0)
    s = np.linalg.svd(R / np.where(norms > 0, norms, 1.0), compute_uv=False)
    return int(np.sum(s > RANK_TOL * max(s.max(), 1e-300)))


def _check_psd(links, solver, what):
    eig = [float(np.linalg.eigvalsh(pseudo_inertia(p)).min()) for p in links]
    if min(eig) < -1e-6 * max(1.0, float(np.abs(links).max())):
        raise SolverError(f"solver {solver} returned a pseudo-inertia with eigenvalue {min(eig):.3g} < 0 ({what})")
    return eig


def _regularise(R_full, K, prior, n_links, n_extra, bounds, rows, inflation, S0, extents, bodies):
    """(regularised_fit output, regularisation report) with the budget S_0 + Delta (module docstring)."""
    R, _, rss = _compress(None, None, R_full)
    allow = misfit_allowance(rss, rows, _rank(R), inflation)
    J0s, floored = prior_pseudo_inertias(prior[:10 * n_links].reshape(n_links, 10), extents)
    # whiten the misfit by c s^2 so the cone's numbers are chi-square sized
    scale = max(allow["inflation"] * allow["sigma2"], 1e-300)
    Rs = R_full / math.sqrt(scale)
    budget = (S0 + allow["allowance"]) / scale
    reg = regularised_fit(Rs, K, J0s, n_links, n_extra, budget=budget, ia_prior=prior[10 * n_links:],
                          c_lower=bounds[0], c_upper=bounds[1])
    info = {"rule": "min sum_i d(J_i || J0_i) (log-det divergence to the URDF, Lee, Wensing & Park 2020) s.t. "
                    "misfit <= S_0 + c s^2 chi2_r(level) (S_0: nearest feasible point's misfit)",
            "misfit_nearest": float(S0), "misfit_regularised": float(reg["misfit"] * scale),
            "binding": bool(reg["misfit"] > 0.999 * budget), "divergence": [float(x) for x in reg["divergence"]],
            **allow, "solver": reg["solver"],
            "prior_floored": [bodies[i] for i in floored],
            "notes": [f"link {bodies[i]}: singular URDF pseudo-inertia (massless frame or point mass): prior + "
                      f"{PRIOR_FLOOR:g} x a uniform cube of its extent, mass from its neighbours' scale"
                      for i in floored]}
    return reg, info


def consistent_identification(regressor, robot, A, b, n_extra: int, R_full=None, *, rows: int | None = None,
                              inflation: float = 1.0, rotor=(), regularise: bool = True) -> ConsistentResult:
    """Consistent estimate for the weighted stacked problem A x ~ b, x = [theta_base | extras].

    Uses the regressor's own map ``theta_base = K pi`` and its URDF values as the prior. ``rotor``:
    :class:`RotorCandidate` of the last ``len(rotor)`` extra columns. With ``regularise`` (and
    ``rows``, the number of weighted equation rows, known: default len(b)) the result is program 2
    of the module docstring, else program 1; both are reported, with the plausibility check."""
    names = list(regressor.standard_names)
    n_links = sum(1 for nm in names if nm.startswith("m_"))
    bodies = [names[10 * i][2:] for i in range(n_links)]
    prior = np.asarray(regressor.standard_parameters(), float)
    K = np.asarray(regressor.K, float)
    if R_full is None:
        R_full = np.linalg.qr(np.column_stack([A, b]), mode="r")
        rows = len(b) if rows is None else rows
    lo, hi = np.full(n_extra, -np.inf), np.full(n_extra, np.inf)
    for k, r in enumerate(rotor):
        lo[n_extra - len(rotor) + k], hi[n_extra - len(rotor) + k] = 0.0, r.upper
    pis, cs, solver = consistent_fit(None, None, K, prior, n_links, n_extra, R_full=R_full, c_lower=lo, c_upper=hi)
    nearest = pis[:10 * n_links].reshape(n_links, 10)
    nearest_extras = {nm: float(v) for nm, v in zip(names[10 * n_links:], pis[10 * n_links:])}
    _check_psd(nearest, solver, "nearest feasible point")
    prior_links = prior[:10 * n_links].reshape(n_links, 10)
    extents, sources = link_extents(regressor, bodies, prior_links)
    info = {"applied": False, "extents": dict(zip(bodies, extents)), "extent_sources": dict(zip(bodies, sources))}
    if regularise and rows:
        R, z, _ = _compress(None, None, R_full)
        M = np.zeros((R.shape[0], len(pis) + n_extra))
        M[:K.shape[0], :len(pis)], M[K.shape[0]:, len(pis):] = K, np.eye(n_extra)
        S0 = float(np.sum((R @ M @ np.concatenate([pis, cs]) - z) ** 2))
        try:
            reg, more = _regularise(R_full, K, prior, n_links, n_extra, (lo, hi), rows, inflation, S0, extents,
                                     bodies)
            _check_psd(reg["pi"][:10 * n_links].reshape(n_links, 10), reg["solver"], "regularised fit")
            pis, cs, solver = reg["pi"], reg["c"], reg["solver"]
            info.update(applied=True, **more)
        except (SolverError, np.linalg.LinAlgError) as exc:
            info["failed"] = f"regularised fit not available, nearest feasible point used: {exc}"
    links = pis[:10 * n_links].reshape(n_links, 10)
    eig = [float(np.linalg.eigvalsh(pseudo_inertia(p)).min()) for p in links]
    n0 = n_extra - len(rotor)
    theta = np.concatenate([K @ pis, cs[:n0]])
    extras = {nm: float(v) for nm, v in zip(names[10 * n_links:], pis[10 * n_links:])}
    rot = np.maximum(np.asarray(cs[n0:], float), 0.0)  # >= 0 up to the solver's round-off
    extras.update({f"Ia_{r.name}": float(v) for r, v in zip(rotor, rot)})
    return ConsistentResult(theta=theta, pi=links, body_names=bodies, min_eig=eig, solver=solver, extras=extras,
                            nearest_pi=nearest, nearest_extras=nearest_extras, regularisation=info,
                            plausibility=plausibility_report(links, prior_links, bodies, extents),
                            rotor_theta=rot, rotor=list(rotor))


def set_plant_inertias(plant, context, body_names, pi, extras=None) -> None:
    """Write standard parameters (and reflected inertias ``Ia_<joint>``) into a plant context."""
    for name, p in zip(body_names, pi):
        body = plant.GetBodyByName(name)
        body.SetSpatialInertiaInBodyFrame(context, _spatial_inertia(np.asarray(p, float)))
    for key, val in (extras or {}).items():
        if key.startswith("Ia_"):
            jname = key[3:]
            for ai in plant.GetJointActuatorIndices():
                act = plant.get_joint_actuator(ai)
                if act.joint().name() == jname:
                    G = act.default_gear_ratio()
                    act.SetRotorInertia(context, float(val) / (G * G))
