"""Ultimate tracking-error bound of Calafiore & Indri's eq. 15 controller on an n-joint arm, per
joint, and the boundary layer that keeps it small.

Closed loop (CI eqs. 6-8, 15; plant M(q) q'' + C q' + g = D(q, q', v, a) theta): with r = e' +
Lambda e, v = q_d' - Lambda e, a = q_d'' - Lambda e' and tau = D theta0 - K r + D u,

    M r' + C r = -K r + D (theta0 - theta + u),  theta - theta0 = E z, ||z|| <= 1 (CI eq. 10).

V = 1/2 r^T M r (JS seed 001 eq. 20, Spong [11]); M' - 2C skew (JS eq. 6) gives
V' = -r^T K r + r^T D (theta0 - theta + u). With w = E^T D^T r, r^T D E z <= ||w|| and eq. 15's
u = -E w / max(||w||, epsilon): the uncertain term is <= ||w|| - ||w||^2 / epsilon <= epsilon / 4
inside the layer, <= 0 outside. Two bounds follow.

* Norm bound (:func:`norm_bound`, the first version): V' <= -k_min ||r||^2 + epsilon / 4, so V
  ultimately stays below its largest value on the ball ||r||^2 <= epsilon / (4 k_min), and
  ||r|| <= sqrt(m_max / m_min) sqrt(epsilon / (4 k_min)); |e_j| <= ||r|| / lambda_min.
* Per-joint bound (:func:`per_joint_bound`, used): r^T K r >= kappa r^T M r with
  kappa = min over q of lambda_min(M^-1 K) (generalised eigenvalue of (K, M)), so
  V' <= -2 kappa V + epsilon / 4 and ultimately r^T M r <= epsilon / (4 kappa). By Cauchy-Schwarz
  |r_j| = |(M^-1/2 e_j)^T M^1/2 r| <= sqrt((M^-1)_jj) sqrt(r^T M r), so
  |r_j| <= sqrt(max_q (M^-1)_jj epsilon / (4 kappa)), and e_j' = -Lambda_j e_j + r_j gives
  |e_j| <= |r_j| / Lambda_j ultimately. Since kappa >= k_min / m_max and (M^-1)_jj <= 1 / m_min it
  is never above the norm bound (same derivation as ``spong.spong_ultimate_bound`` for SP1).

Where M is taken (:func:`bound_region`): when at most two joints change M(q) and all joints are
revolute, a grid of 73 angles over [-pi, pi] per such joint (the other joints do not enter M), a
global bound (the 2-link arms: the elbow; the PUMA's first three joints: shoulder and elbow).
Otherwise the reference tube: q_d(t) at the loop's samples plus points at +-delta (corners up to 4
joints, random points beyond) around each; the bound then holds once the error is inside the tube,
so it is self-consistent only when every joint's bound is <= delta (reported as ``consistent``).
Both are sampled extremes, not certified ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: angles per M-joint of the global grid over [-pi, pi]
GRID = 73
#: half width [rad] of the neighbourhood of the reference tube
TUBE_DELTA = 0.05


@dataclass
class MassBounds:
    """Extremes of M(q) [kg m^2] over a set of configurations, for gain K [N m s/rad]:
    ``kappa`` = min lambda_min(M^-1 K) [1/s], ``minv`` = max (M^-1)_jj per joint [1/(kg m^2)],
    ``m_min``/``m_max`` extreme eigenvalues of M, ``k_min`` = min K_j."""

    kappa: float
    minv: tuple
    m_min: float
    m_max: float
    k_min: float
    points: int


def mass_joints(plant, ctx, rng, probes: int = 6) -> list:
    """Joints whose position changes M(q) (relative change > 1e-9 at random configurations)."""
    n = plant.num_positions()
    out = []
    for j in range(n):
        for _ in range(probes):
            q = rng.uniform(-np.pi, np.pi, n)
            plant.SetPositions(ctx, q)
            M0 = plant.CalcMassMatrix(ctx)
            q[j] += rng.uniform(0.3, 2.5)
            plant.SetPositions(ctx, q)
            if np.abs(plant.CalcMassMatrix(ctx) - M0).max() > 1e-9 * np.abs(M0).max():
                out.append(j)
                break
    return out


def _all_revolute(plant) -> bool:
    from pydrake.multibody.tree import JointIndex

    js = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
    return all(j.type_name() in ("revolute", "weld") for j in js)


def bound_region(plant, q_ref, rng, delta: float = TUBE_DELTA):
    """(points (N, n), description) where M is taken (module docstring)."""
    ctx = plant.CreateDefaultContext()
    n = plant.num_positions()
    mj = mass_joints(plant, ctx, rng)
    if len(mj) <= 2 and _all_revolute(plant):
        axes = np.meshgrid(*([np.linspace(-np.pi, np.pi, GRID)] * len(mj)), indexing="ij")
        pts = np.zeros((axes[0].size if mj else 1, n))
        for k, j in enumerate(mj):
            pts[:, j] = axes[k].ravel()
        return pts, {"kind": "global", "joints": mj, "grid": GRID}
    q_ref = np.asarray(q_ref, float).reshape(-1, n)
    if n <= 4:
        corners = np.array(np.meshgrid(*([[-1.0, 1.0]] * n), indexing="ij")).reshape(n, -1).T
    else:
        corners = rng.choice([-1.0, 1.0], size=(16, n))
    pts = np.concatenate([q_ref] + [q_ref + delta * c for c in corners])
    return pts, {"kind": "tube", "joints": mj, "delta": delta, "reference_samples": int(len(q_ref))}


def mass_bounds(plant, ctx, points, K) -> MassBounds:
    """:class:`MassBounds` of ``plant`` (its parameters in ``ctx``) over ``points``."""
    from scipy.linalg import eigh

    n = plant.num_positions()
    Kd = np.diag(np.broadcast_to(np.asarray(K, float), (n,)))
    kap, minv, lo, hi = np.inf, np.zeros(n), np.inf, 0.0
    for q in points:
        plant.SetPositions(ctx, q)
        M = plant.CalcMassMatrix(ctx)
        w = np.linalg.eigvalsh(M)
        lo, hi = min(lo, w[0]), max(hi, w[-1])
        kap = min(kap, float(eigh(Kd, M, eigvals_only=True)[0]))
        minv = np.maximum(minv, np.diag(np.linalg.inv(M)))
    return MassBounds(float(kap), tuple(minv.tolist()), float(lo), float(hi), float(np.min(np.diag(Kd))),
                      int(len(points)))


def per_joint_bound(epsilon: float, mb: MassBounds, Lambda) -> list:
    """|e_j| <= sqrt(max (M^-1)_jj epsilon / (4 kappa)) / Lambda_j [rad] (module docstring)."""
    lam = np.broadcast_to(np.asarray(Lambda, float).ravel() if np.ndim(Lambda) < 2
                          else np.diag(Lambda), (len(mb.minv),))
    return (np.sqrt(np.asarray(mb.minv) * float(epsilon) / (4.0 * mb.kappa)) / lam).tolist()


def norm_bound(epsilon: float, mb: MassBounds, Lambda) -> float:
    """max_j |e_j| <= sqrt(m_max / m_min) sqrt(epsilon / (4 k_min)) / lambda_min [rad]."""
    lam = float(np.min(np.diag(Lambda) if np.ndim(Lambda) == 2 else Lambda))
    return float(np.sqrt(mb.m_max / mb.m_min) * np.sqrt(epsilon / (4.0 * mb.k_min)) / lam)


def mass_matrices(reg, theta, q) -> np.ndarray:
    """M(q_k) [kg m^2], (N, n, n), of base parameters ``theta`` from the regressor alone (M is
    linear in theta): column j is Y(q, 0, e_j) theta - Y(q, 0, 0) theta; no plant needs to realise
    theta (the identified centre need not be a physically valid arm)."""
    q = np.asarray(q, float).reshape(-1, reg.n)
    N, n = q.shape
    Q = np.repeat(q, n + 1, axis=0)
    A = np.tile(np.vstack([np.zeros(n), np.eye(n)]), (N, 1))
    tau = (reg.evaluate(Q, np.zeros_like(Q), A) @ np.asarray(theta, float)).reshape(N, n + 1, n)
    return np.transpose(tau[:, 1:, :] - tau[:, :1, :], (0, 2, 1))


def sampled_layer(D_samples, E, M_samples, K, period: float) -> float:
    """Smallest boundary layer of eq. 15 the sampled loop tolerates (the bound is ~ sqrt(epsilon)).

    Inside the layer eq. 15 is u = -E E^T D^T r / epsilon: it adds the gain D P D^T / epsilon to K
    (P = E E^T), M r' = -(K + D P D^T / epsilon) r + ... Sampled with period h the loop needs
    h lambda_max(M^-1 (K + D P D^T / epsilon)) below 2 (explicit Euler); with the margin beta =
    ``spong.SAMPLED_BETA`` and g_max = max_k ||M_k^-1/2 D_k E||_2^2, k_max = max_k lambda_max(M_k^-1 K)
    over the reference samples (q_d, q_d', q_d', q_d'') this is ``spong.sampled_epsilon`` with rho = 1:
    epsilon = g_max h / (beta - h k_max) [units of ||E^T D^T r||, N m rad/s]."""
    from scipy.linalg import eigh

    from robust_drake.systems.controllers.spong import ReferenceTube, sampled_epsilon

    Kd = np.diag(np.asarray(K, float))
    g, kmax = 0.0, 0.0
    for D, M in zip(D_samples, M_samples):
        w, V = np.linalg.eigh(M)
        Mih = (V / np.sqrt(w)) @ V.T
        g = max(g, float(np.linalg.norm(Mih @ D @ E, 2)) ** 2)
        kmax = max(kmax, float(eigh(Kd, M, eigvals_only=True)[-1]))
    tube = ReferenceTube(g, kmax, 0.0, (), len(D_samples))
    return float(sampled_epsilon(1.0, tube, period))
