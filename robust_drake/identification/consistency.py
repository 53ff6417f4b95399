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
A = Q R, z = Q^T b, so the SDP sees a p x p triangle instead of N n rows::

    min_{pi, c}  || R [K pi; c] - z ||^2 + lambda || pi - pi_prior ||^2
    s.t.         J_i(pi_i) >= 0, m_i >= m_min          for every link i

``pi_prior`` is the URDF's inertia (small ``lambda`` pins the directions the data cannot see to
the URDF instead of an arbitrary consistent point). Solved with ``MathematicalProgram``
(Clarabel/SCS/CSDP, whichever Drake picks) and checked afterwards (eigenvalues of every J_i).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robust_drake.errors import SolverError

PRIOR_WEIGHT = 1e-6  # lambda relative to trace(R^T R) / p
M_MIN = 1e-4  # kg


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


@dataclass
class ConsistentResult:
    theta: np.ndarray  # full parameter vector [theta_base (consistent) | extra coefs]
    pi: np.ndarray  # (nb, 10) standard parameters per link
    body_names: list[str]
    min_eig: list[float]  # smallest eigenvalue of every J_i (>= -tol)
    solver: str
    extras: dict | None = None  # reflected inertias / damping of the URDF's transmissions


    def as_dict(self):
        return {"bodies": {b: {"mass": float(p[0]), "com": (p[1:4] / p[0]).tolist(), "inertia_origin": p[4:10].tolist()}
                           for b, p in zip(self.body_names, self.pi)},
                "min_pseudo_inertia_eig": [float(x) for x in self.min_eig], "solver": self.solver,
                "extras": self.extras or {}}


def consistent_fit(A: np.ndarray | None, b: np.ndarray | None, K: np.ndarray, pi_prior: np.ndarray, n_links: int,
                   n_extra: int, prior_weight: float = PRIOR_WEIGHT, m_min: float = M_MIN,
                   R_full: np.ndarray | None = None):
    """Solve the compressed SDP. A: (rows, p_base + n_extra) weighted regressor, b: rows.

    ``pi`` = [10 per link | non-negative extras (reflected inertia, damping)], theta_base = K pi.
    ``R_full``: the R factor of [A | b] already computed (``ColumnCache.qr_r``, by row blocks);
    then A and b are not used. Returns (pi (p_std,), extra coefficients (n_extra,), solver name)."""
    from pydrake.solvers import MathematicalProgram, Solve

    p_base, p_std = K.shape
    # compression: R of the QR factorisation of [A | b]; ||A x - b||^2 = ||R x - z||^2 + const
    if R_full is None:
        R_full = np.linalg.qr(np.column_stack([A, b]), mode="r")
    p = R_full.shape[1] - 1
    R, z = R_full[:p, :p], R_full[:p, p]
    prog = MathematicalProgram()
    pi = prog.NewContinuousVariables(p_std, "pi")
    c = prog.NewContinuousVariables(n_extra, "c") if n_extra else np.zeros(0, dtype=object)
    M = np.zeros((p, p_std + n_extra))
    M[:p_base, :p_std] = K
    M[p_base:, p_std:] = np.eye(n_extra)
    RM = R @ M
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
    bcone = np.concatenate([[0.0], -rows_b])
    prog.AddLorentzConeConstraint(Acone, bcone, np.concatenate([[t], x]))
    prog.AddLinearCost(np.array([1.0]), [t])
    F = [_J_coeff(k) for k in range(10)]
    for i in range(n_links):
        v = pi[10 * i:10 * i + 10]
        prog.AddLinearMatrixInequalityConstraint([np.zeros((4, 4))] + F, v)
        if pi_prior[10 * i] > 0:
            prog.AddBoundingBoxConstraint(m_min, np.inf, v[0])
    for k in range(10 * n_links, p_std):
        prog.AddBoundingBoxConstraint(0.0, np.inf, pi[k])
    result = Solve(prog)
    from robust_drake.log import debug_solve

    debug_solve("physically consistent fit (pseudo-inertia LMIs)", result)
    name = result.get_solver_id().name()
    if not result.is_success():
        raise SolverError(f"physically consistent fit failed ({name}: {result.get_solution_result()})")
    cs = result.GetSolution(c) if n_extra else np.zeros(0)
    return result.GetSolution(pi), cs, name


def _J_coeff(k: int) -> np.ndarray:
    e = np.zeros(10)
    e[k] = 1.0
    return pseudo_inertia(e)


def consistent_identification(regressor, robot, A, b, n_extra: int, R_full=None) -> ConsistentResult:
    """Consistent estimate for the weighted stacked problem A x ~ b, x = [theta_base | extras].

    Uses the regressor's own map ``theta_base = K pi`` and its URDF values as the prior."""
    names = list(regressor.standard_names)
    n_links = sum(1 for nm in names if nm.startswith("m_"))
    bodies = [names[10 * i][2:] for i in range(n_links)]
    prior = np.asarray(regressor.standard_parameters(), float)
    K = np.asarray(regressor.K, float)
    pis, cs, solver = consistent_fit(A, b, K, prior, n_links, n_extra, R_full=R_full)
    links = pis[:10 * n_links].reshape(n_links, 10)
    eig = [float(np.linalg.eigvalsh(pseudo_inertia(p)).min()) for p in links]
    if min(eig) < -1e-6 * max(1.0, float(np.abs(links).max())):
        raise SolverError(f"solver {solver} returned a pseudo-inertia with eigenvalue {min(eig):.3g} < 0")
    theta = np.concatenate([K @ pis, cs])
    extras = {nm: float(v) for nm, v in zip(names[10 * n_links:], pis[10 * n_links:])}
    return ConsistentResult(theta=theta, pi=links, body_names=bodies, min_eig=eig, solver=solver,
                            extras=extras)


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
