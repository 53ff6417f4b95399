"""Uncertainty bounds of Bascetta & Rocco (BR) section II-C and the rho coefficients.

Quantities (BR, after eq. 8 and eq. 11), all evaluated by sampling:

* ``alpha  = sup_q ||I - M(q)^{-1} M_hat||``            (must be < 1)
* ``B_m = inf_q ||M(q)^{-1}||``,  ``B_M = sup_q ||M(q)^{-1}||``
* ``Q_M = sup_t ||qdd_d(t)||``   (strict in the paper; we report the sampled sup)
* ``||n_tilde(q, qd)|| <= alpha_0 + alpha_1 ||e|| + alpha_2 ||e||^2``   (eq. 11)

Method for eq. 11 (written down as the issue asks). For a rigid arm, ``n_tilde = n_hat - n`` is
the sum of a configuration term ``g~(q) = n_tilde(q, 0)``, a term linear in qd (viscous
friction; zero when neither model has it) ``l~(q, u) = (n_tilde(q, u) - n_tilde(q, -u)) / 2``
and a term quadratic in qd ``c~(q, u) = (n_tilde(q, u) + n_tilde(q, -u)) / 2 - g~(q)``
(Coriolis/centrifugal). With ``G = sup ||g~||``, ``L = sup_{||u||=1} ||l~||``,
``c = sup_{||u||=1} ||c~||`` over the sampled configurations and unit directions u (the linear and
quadratic parts are recovered exactly by polarisation, so only the sup over u is sampled), and
``||qd|| <= ||qd_d|| + ||e|| <= V_M + ||e||`` (V_M = sup_t ||qd_d||):

    alpha_0 = G + L V_M + c V_M^2,   alpha_1 = L + 2 c V_M,   alpha_2 = c.

Configurations: ``region="trajectory"`` samples a tube of radius ``tube`` (rad, per joint, a
3^n grid of offsets while 3^n <= ``max_offsets`` (27); for more joints the centre, the 2n axis
points +-tube e_i and ``n_vertices`` (16) random tube vertices, fixed seed) around q_d(t) on
``n_time`` instants; ``region="workspace"`` a regular grid over [-pi, pi]^n. Unit directions u:
``n_dir`` angles on the half circle (n = 2, with a Bernstein correction); for n > 2 the sup over
||u|| = 1 of ||sum_jk Gam[:, j, k] u_j u_k|| is bounded above without sampling by
sqrt(sum_i ||Gam_i||_2^2) (each component is a quadratic form u^T Gam_i u). The sup over the
trajectory region is valid while the tracking error stays in the tube, which the case study checks
after simulating.

``M_hat`` may be a constant matrix (the case study's diag(M(0))) or a function ``M_hat(q)`` (BR
eq. 2 allows M_hat(q): for arms with strong inertial coupling a constant diagonal M_hat gives
alpha >= 1, e.g. 1.21 on serial7 along the sine, and eq. 13 has no solution).

Coefficients: Case A (eq. 13), with ||K|| = ||[K_P K_D]||_2, the norm that bounds
||K_P q~ + K_D q~dot|| / ||e|| (the paper writes ||diag(K_P, K_D)||, which is slightly smaller):

    beta_0 = (alpha Q_M + alpha_0 B_M)/(1 - alpha),  beta_1 = (alpha ||K|| + alpha_1 B_M)/(1 - alpha),
    beta_2 = alpha_2 B_M / (1 - alpha);

Case B (eq. 20): the same without the alpha ||K|| term in beta_1.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass

import numpy as np

from robust_drake.errors import RobustDrakeError


@dataclass
class UncertaintyBounds:
    alpha: float
    B_m: float
    B_M: float
    Q_M: float
    V_M: float
    alpha_0: float
    alpha_1: float
    alpha_2: float
    G: float  # sup ||n_tilde(q, 0)||
    L: float  # sup linear-in-qd part
    c: float  # sup quadratic-in-qd part
    region: str
    n_configs: int

    def to_dict(self):
        return asdict(self)


def sample_configurations(region: str, n: int, q_d=None, tube: float = 0.1, grid: int = 73,
                          max_offsets: int = 27, n_vertices: int = 16, seed: int = 0):
    """Configurations to take sups over (see module docstring)."""
    if region == "workspace":
        if grid ** n > 10 ** 6:
            raise RobustDrakeError(f"region='workspace' would grid {grid}^{n} configurations; use "
                                   "region='trajectory' for arms with more than a few joints")
        axis = np.linspace(-np.pi, np.pi, grid)
        return np.array(list(itertools.product(*([axis] * n))))
    if region == "trajectory":
        if q_d is None:
            raise RobustDrakeError("region='trajectory' needs the sampled q_d (K x n)")
        if 3 ** n <= max_offsets:
            offsets = np.array(list(itertools.product(*([[-tube, 0.0, tube]] * n))))
        else:
            eye = np.eye(n)
            verts = tube * np.random.default_rng(seed).choice([-1.0, 1.0], size=(n_vertices, n))
            offsets = np.vstack([np.zeros((1, n)), tube * eye, -tube * eye, verts])
        return (np.asarray(q_d)[:, None, :] + offsets[None, :, :]).reshape(-1, n)
    raise RobustDrakeError(f"unknown region {region!r}; use 'trajectory' or 'workspace'")


def unit_directions(n: int, n_dir: int = 90, seed: int = 0):
    if n == 1:
        return np.array([[1.0]])
    if n == 2:
        phi = np.linspace(0.0, np.pi, n_dir, endpoint=False)
        return np.stack([np.cos(phi), np.sin(phi)], axis=1)
    u = np.random.default_rng(seed).normal(size=(n_dir * n, n))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _poly_parts(f, q, n):
    """Split ``f(q, qd)`` (constant + linear + quadratic in qd) by polarisation:
    returns ``(g0, Lmat, Gam)`` with ``f(q, u) = g0 + Lmat u + sum_jk Gam[:, j, k] u_j u_k``
    (Gam symmetric in j, k), from evaluations at 0, +-e_i and +-(e_i + e_j)."""
    g0 = f(q, np.zeros(n))
    E = np.eye(n)
    Lmat = np.zeros((len(g0), n))
    Gam = np.zeros((len(g0), n, n))
    even = {}
    for i in range(n):
        fp, fm = f(q, E[i]), f(q, -E[i])
        Lmat[:, i] = 0.5 * (fp - fm)
        Gam[:, i, i] = 0.5 * (fp + fm) - g0
    for i in range(n):
        for j in range(i + 1, n):
            d = E[i] + E[j]
            h = 0.5 * (f(q, d) + f(q, -d)) - g0
            Gam[:, i, j] = Gam[:, j, i] = 0.5 * (h - Gam[:, i, i] - Gam[:, j, j])
    return g0, Lmat, Gam


def compute_bounds(M_fn, n_fn, n_hat_fn, M_hat, configs, qd_d, qdd_d, n_dir: int = 180,
                   region: str = "trajectory") -> UncertaintyBounds:
    """alpha, B_m, B_M, Q_M and alpha_0..2 of BR eqs. 9-11 by sampling.

    ``M_fn(q)`` true inertia; ``n_fn(q, qd)`` true ``C qd + F qd + g``; ``n_hat_fn`` its estimate;
    ``configs`` (K x n) sampled configurations; ``qd_d``, ``qdd_d`` (T x n) the reference samples.
    The linear and quadratic parts in qd are recovered exactly by polarisation (7 evaluations per
    configuration for n = 2); the sup over unit directions is then taken on ``n_dir`` samples.
    """
    M_hat_fn = M_hat if callable(M_hat) else (lambda q, _M=np.asarray(M_hat, float): _M)
    n = np.asarray(configs).shape[1]
    U = unit_directions(n, n_dir) if n <= 2 else None
    UU = np.einsum("kj,kl->kjl", U, U) if U is not None else None

    def f(q, v):
        return n_hat_fn(q, v) - n_fn(q, v)

    alpha = 0.0
    Bm, BM = np.inf, 0.0
    G = L = c = 0.0
    for q in configs:
        Minv = np.linalg.inv(M_fn(q))
        alpha = max(alpha, np.linalg.norm(np.eye(n) - Minv @ M_hat_fn(q), 2))
        s = np.linalg.norm(Minv, 2)
        Bm, BM = min(Bm, s), max(BM, s)
        g0, Lmat, Gam = _poly_parts(f, q, n)
        G = max(G, np.linalg.norm(g0))
        L = max(L, np.linalg.norm(Lmat, 2))
        if UU is not None:
            quad = np.einsum("ijk,mjk->mi", Gam, UU)
            c = max(c, float(np.max(np.linalg.norm(quad, axis=1))))
        else:  # sup_u ||(u^T Gam_i u)_i|| <= sqrt(sum_i ||Gam_i||_2^2), no sampling of u
            c = max(c, float(np.sqrt(np.sum(np.linalg.norm(Gam, 2, axis=(1, 2)) ** 2))))
    if n == 2:
        # ||Q(u(phi))||^2 is a trig polynomial of degree 4, so (Bernstein) its second derivative is at
        # most 16 max; a sample within h = pi / (2 n_dir) of the peak is >= max (1 - 8 h^2).
        h = np.pi / (2 * n_dir)
        c /= np.sqrt(1.0 - 8.0 * h * h)
    if alpha >= 1.0:
        raise RobustDrakeError(
            f"alpha = sup ||I - M^-1 M_hat|| = {alpha:.4g} >= 1: BR eq. 13 has no solution; improve M_hat "
            "(controller_params mass_model='model' uses M_hat(q) of the controller's model)"
        )
    V_M = float(np.max(np.linalg.norm(np.asarray(qd_d), axis=1)))
    Q_M = float(np.max(np.linalg.norm(np.asarray(qdd_d), axis=1)))
    return UncertaintyBounds(
        alpha=float(alpha), B_m=float(Bm), B_M=float(BM), Q_M=Q_M, V_M=V_M,
        alpha_0=float(G + L * V_M + c * V_M**2), alpha_1=float(L + 2 * c * V_M), alpha_2=float(c),
        G=float(G), L=float(L), c=float(c), region=region, n_configs=len(configs),
    )


def gain_norm(K_P, K_D) -> float:
    """``||[K_P K_D]||_2`` (see module docstring)."""
    kp = np.atleast_1d(np.diag(K_P) if np.ndim(K_P) == 2 else K_P).astype(float)
    kd = np.atleast_1d(np.diag(K_D) if np.ndim(K_D) == 2 else K_D).astype(float)
    return float(np.linalg.norm(np.hstack([np.diag(kp), np.diag(kd)]), 2))


def beta_case_a(b: UncertaintyBounds, K_P, K_D):
    """BR eq. 13 (equalities): [beta_0, beta_1, beta_2] of Case A; beta_1 grows with the gains."""
    k = 1.0 - b.alpha
    return [
        (b.alpha * b.Q_M + b.alpha_0 * b.B_M) / k,
        (b.alpha * gain_norm(K_P, K_D) + b.alpha_1 * b.B_M) / k,
        b.alpha_2 * b.B_M / k,
    ]


def beta_case_b(b: UncertaintyBounds):
    """BR eq. 20 (equalities): [beta_0, beta_1, beta_2] of Case B; independent of K_P, K_D."""
    k = 1.0 - b.alpha
    return [
        (b.alpha * b.Q_M + b.B_M * b.alpha_0) / k,
        b.B_M * b.alpha_1 / k,
        b.B_M * b.alpha_2 / k,
    ]


def rho(beta, e_norm):
    """``rho(||e||) = beta_0 + beta_1 ||e|| + beta_2 ||e||^2`` (BR eqs. 12, 19)."""
    return beta[0] + beta[1] * e_norm + beta[2] * e_norm * e_norm
