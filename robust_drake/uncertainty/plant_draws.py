"""Plants drawn across a confidence ellipsoid of base parameters, each a physically valid arm.

A draw is a base-parameter vector theta = theta0 + E z (CI eq. 10, E^T E = P): on the boundary
(||z|| = 1, a uniform direction) or inside (z uniform in the unit ball, ||z|| = u^(1/p)). It is
realised as a plant by changing the URDF's standard parameters pi (theta = K pi,
``InverseDynamicsRegressor.K``) by the smallest relative change that reaches theta:

    delta_pi = W K^T (K W K^T)^-1 (theta - K pi_nom),   W = diag(pi_nom_i^2 + body scale^2) on
    the allowed entries (first moments: scale m r_g; rotational inertias: m r_g^2, r_g^2 = half
    the trace of the body's inertia over m; reflected rotor inertias: their value), 0 on the
    masses and joint damping (kept as in the URDF),

then made physically valid where only unidentifiable entries allow it: a body's rotational
inertia about its centre of mass must be positive semidefinite and satisfy the triangle
inequality; only the inertia entries K does not see (columns of K equal to zero, e.g. Ixx, Iyy,
Ixy of a planar arm) are changed for that (:func:`make_physical`). Where that cannot repair a body
(a 3D arm, whose null space of K mixes several links' entries) a small SDP finds the nearest pi
with K pi = theta whose every body's pseudo-inertia is positive definite (:class:`PhysicalBySdp`;
Wensing, Kim & Slotine 2018). A draw no rigid body with these masses realises is drawn again
(counted); after ``tries`` of them the nearest valid point of the set replaces it
(:class:`NearestPhysical`). Every kept plant's base parameters are recomputed by Drake from the
modified plant and must equal theta.

Both SDPs are Drake ``MathematicalProgram`` s (4x4 LMIs per body, a Lorentz cone for the set,
quadratic costs; Drake's Clarabel), built once per draw_plants call and updated per theta (the
equality's bounds, the cost's linear term): median 3-9 ms a call on the PUMA and serial7 against
7-10 ms for the same problems in cvxpy with theta a Parameter (30 calls each, interleaved, loaded
2-core machine, 2026-12-02). Every solution is certified without the
solver before it is used (:func:`physical_certificate`, :func:`reaches`, the set's radius); a
failed certificate counts as no plant (the caller draws again). tests/test_plant_draws_sdp.py
cross-checks both programs against cvxpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robust_drake.errors import RobustDrakeError


@dataclass
class PlantDraw:
    """One drawn plant: ``theta`` its base parameters, ``radius`` = ||z|| (Mahalanobis radius in
    the set), ``kind`` "boundary" or "interior", ``setup(plant, context)`` applies it."""

    theta: np.ndarray
    radius: float
    kind: str
    pi: np.ndarray
    setup: object
    projected: bool = False


def _allowed(reg) -> np.ndarray:
    """Standard entries a draw may change: per body [m, mc(3), I(6)] -> mc and I; extras Ia."""
    ok = np.zeros(reg.p_standard, bool)
    for k in range(len(reg._nodes)):
        ok[10 * k + 1:10 * k + 10] = True
    base = 10 * len(reg._nodes)
    for c, (_, kind, _) in enumerate(reg._extras):
        ok[base + c] = kind == "Ia"
    return ok


def _weights(reg, pi_nom) -> np.ndarray:
    """W of the module docstring (0 on the entries a draw keeps)."""
    w = np.where(_allowed(reg), pi_nom ** 2, 0.0)
    for k in range(len(reg._nodes)):  # body scales: m r_g [kg m] and m r_g^2 [kg m^2]
        m = max(pi_nom[10 * k], 0.0)
        rg2 = np.sum(pi_nom[10 * k + 4:10 * k + 7]) / (2.0 * m) if m > 0 else 0.0
        w[10 * k + 1:10 * k + 4] += m * m * rg2
        w[10 * k + 4:10 * k + 10] += (m * rg2) ** 2
    base = 10 * len(reg._nodes)
    w[base:] += np.where(w[base:] > 0, 0.0, 1e-6 * (w.max() if w.max() > 0 else 1.0))
    return w * _allowed(reg)


def _reach(reg, theta, pi, w) -> np.ndarray:
    """pi + W K^T (K W K^T)^-1 (theta - K pi): the smallest weighted change with K pi = theta."""
    K = np.asarray(reg.K, float)
    KW = K * w
    d = np.linalg.lstsq(KW @ K.T, np.asarray(theta, float) - K @ pi, rcond=None)[0]
    out = pi + KW.T @ d
    if not np.allclose(K @ out, theta, rtol=1e-9, atol=1e-12 * max(np.abs(theta).max(), 1.0)):
        raise RobustDrakeError("these base parameters cannot be reached with the masses kept")
    return out


def standard_for_base(reg, theta, pi_nom=None) -> np.ndarray:
    """pi with K pi = theta, nearest to pi_nom in relative terms (module docstring)."""
    pi_nom = reg.standard_parameters() if pi_nom is None else np.asarray(pi_nom, float)
    return _reach(reg, theta, pi_nom, _weights(reg, pi_nom))


def pseudo_inertia(body) -> np.ndarray:
    """Pseudo-inertia J = [[tr(I)/2 1 - I, h], [h^T, m]] [kg m^2 | kg m | kg] of a body's standard
    parameters [m, hx, hy, hz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (inertia about the body origin):
    J >= 0 iff a mass density realises the body (Wensing, Kim & Slotine, IEEE RA-L 2018, eq. 8).
    Linear in the parameters."""
    m, hx, hy, hz, ixx, iyy, izz, ixy, ixz, iyz = (float(v) for v in body)
    t = 0.5 * (ixx + iyy + izz)
    return np.array([[t - ixx, -ixy, -ixz, hx], [-ixy, t - iyy, -iyz, hy], [-ixz, -iyz, t - izz, hz],
                     [hx, hy, hz, m]])


_J_BASIS = np.array([pseudo_inertia(e) for e in np.eye(10)])  # J(body) = sum_j body_j _J_BASIS[j]


def body_scale(pi_nom, k: int) -> np.ndarray:
    """D^-1/2 of body k, D = diag(m r_g^2 (x3), m) of the URDF body (r_g^2 = tr(I) / (2 m), I about
    the origin): D^-1/2 J D^-1/2 is dimensionless and ~1 for the URDF body."""
    m = float(pi_nom[10 * k])
    s = max(float(np.sum(pi_nom[10 * k + 4:10 * k + 7])) / 2.0, 1e-12)
    return 1.0 / np.sqrt(np.array([s, s, s, m]))


def _rotor_entries(reg) -> np.ndarray:
    base = 10 * len(reg._nodes)
    return np.array([base + c for c, (_, kind, _) in enumerate(reg._extras) if kind == "Ia"], int)


def physical_certificate(reg, pi, pi_nom, margin: float) -> bool:
    """Solver-free check of the physical constraints of :class:`PhysicalBySdp` on pi: every body's
    scaled pseudo-inertia Jn = D^-1/2 J D^-1/2 (:func:`body_scale`) has lambda_min(Jn) >= margin -
    tol and lambda_min(Jn) > rounding (strictly a rigid body), masses are the URDF's, and every
    reflected rotor inertia is >= 0. tol = SDP_RTOL ||Jn||_2 (the solver's feasibility accuracy,
    relative to the data, ``analysis.tolerance``) plus the eigenvalue rounding ``psd_tol`` (a
    symmetric eigenvalue has condition number 1)."""
    from robust_drake.analysis.tolerance import SDP_RTOL, psd_tol

    pi, pi_nom = np.asarray(pi, float), np.asarray(pi_nom, float)
    if not np.all(np.isfinite(pi)):
        return False
    for k in range(len(reg._nodes)):
        if pi[10 * k] != pi_nom[10 * k]:
            return False
        if pi_nom[10 * k] <= 0:
            continue
        d = body_scale(pi_nom, k)
        lam = np.linalg.eigvalsh(np.outer(d, d) * pseudo_inertia(pi[10 * k:10 * k + 10]))
        rounding = psd_tol(lam)
        if lam[0] < margin - SDP_RTOL * np.abs(lam).max() - rounding or lam[0] <= rounding:
            return False
    return bool(np.all(pi[_rotor_entries(reg)] >= 0.0))


class _PhysicalProgram:
    """The part :class:`PhysicalBySdp` and :class:`NearestPhysical` share, as a Drake
    ``MathematicalProgram``: variables y = (x - pi_nom[free]) / sqrt(W[free]) (the entries a draw
    may change, scaled so that the weighted cost is ||y||^2), pi(y) = pi_nom + sqrt(W) y; per body
    of positive mass the LMI D^-1/2 J(pi) D^-1/2 - margin 1 >= 0 (4x4, :func:`pseudo_inertia`,
    :func:`body_scale`); every reflected rotor inertia >= 0 (a bound on y). Solved with Drake's
    Clarabel."""

    def __init__(self, reg, pi_nom, margin: float):
        from pydrake.solvers import MathematicalProgram

        self.reg, self.pi_nom, self.margin = reg, np.asarray(pi_nom, float), float(margin)
        self.w = _weights(reg, self.pi_nom)
        self.free = np.flatnonzero(self.w > 0)
        self.sw = np.sqrt(self.w[self.free])
        self.prog = MathematicalProgram()
        self.y = self.prog.NewContinuousVariables(len(self.free), "y")
        pos = np.full(len(self.w), -1)
        pos[self.free] = np.arange(len(self.free))
        for k in range(len(reg._nodes)):
            if self.pi_nom[10 * k] <= 0:
                continue
            Dn = np.outer(*(2 * [body_scale(self.pi_nom, k)]))
            js = [j for j in range(10) if pos[10 * k + j] >= 0]
            F0 = Dn * pseudo_inertia(self.pi_nom[10 * k:10 * k + 10]) - self.margin * np.eye(4)
            Fs = [Dn * _J_BASIS[j] * self.sw[pos[10 * k + j]] for j in js]
            self.prog.AddLinearMatrixInequalityConstraint([F0, *Fs], self.y[[pos[10 * k + j] for j in js]])
        ia = [i for i in _rotor_entries(reg) if pos[i] >= 0]
        if ia:
            lb = -self.pi_nom[ia] / self.sw[pos[ia]]
            self.prog.AddBoundingBoxConstraint(lb, np.full(len(ia), np.inf), self.y[pos[ia]])
        self.KS = np.asarray(reg.K, float)[:, self.free] * self.sw  # K pi(y) = K pi_nom + KS y
        self.K_nom = np.asarray(reg.K, float) @ self.pi_nom

    def pi(self, y) -> np.ndarray:
        out = self.pi_nom.copy()
        out[self.free] += self.sw * np.asarray(y, float)
        return out

    def solve(self):
        """(y, cost) at the optimum, or None when Clarabel reports no solution."""
        from pydrake.solvers import ClarabelSolver

        res = ClarabelSolver().Solve(self.prog)
        from robust_drake.log import debug_solve

        debug_solve("nearest physically valid plant", res)
        if not res.is_success():
            return None
        return res.GetSolution(self.y), float(res.get_optimal_cost())


class NearestPhysical:
    """The physically valid plant (constraints of :class:`PhysicalBySdp`) whose base parameters
    K pi lie in E(P, theta0) at Mahalanobis radius <= ``inside`` and are nearest (in P^-1) to a
    drawn theta that no rigid body realises; ties in the null space of K are broken towards pi_nom
    (weight 1e-6 in W): minimise ||L (K pi - theta)||^2 + 1e-6 ||W^-1/2 (pi - pi_nom)||^2
    (L^T L = P^-1) subject to ||L (K pi - theta0)|| <= inside (a Lorentz cone) and the LMIs of
    :class:`_PhysicalProgram`. Built once; a call changes only the cost's linear term. Calling it
    returns pi, or None when the solve fails or its certificate (:func:`physical_certificate`,
    radius <= inside + tol) does not hold."""

    def __init__(self, reg, pi_nom, theta0, P, margin: float = 1e-4, inside: float = 0.999):
        self.core = _PhysicalProgram(reg, pi_nom, margin)
        self.theta0, self.P, self.inside = np.asarray(theta0, float), np.asarray(P, float), float(inside)
        lam, V = np.linalg.eigh(0.5 * (self.P + self.P.T))
        self.L = (V / np.sqrt(lam)).T  # ||L d||^2 = d^T P^-1 d
        c = self.core
        self.A = self.L @ c.KS  # L K pi(y) = L K pi_nom + A y
        self.Q = 2.0 * (self.A.T @ self.A + 1e-6 * np.eye(len(c.free)))
        A_lc = np.vstack([np.zeros((1, len(c.free))), self.A])
        b_lc = np.concatenate([[self.inside], self.L @ (c.K_nom - self.theta0)])
        c.prog.AddLorentzConeConstraint(A_lc, b_lc, c.y)
        self.cost = c.prog.AddQuadraticCost(self.Q, np.zeros(len(c.free)), 0.0, c.y, is_convex=True).evaluator()

    def solve(self, theta):
        """(pi, cost) of the SDP at theta without the certificate, or None."""
        r = self.L @ (self.core.K_nom - np.asarray(theta, float))
        self.cost.UpdateCoefficients(self.Q, 2.0 * self.A.T @ r, float(r @ r), is_convex=True)
        out = self.core.solve()
        return None if out is None else (self.core.pi(out[0]), out[1])

    def radius_ok(self, pi) -> bool:
        """Mahalanobis radius of K pi <= inside + SDP_RTOL + rounding (certificate_tol of cond P)."""
        from robust_drake.analysis.tolerance import SDP_RTOL, certificate_tol

        r = np.linalg.norm(self.L @ (np.asarray(self.core.reg.K, float) @ pi - self.theta0))
        return bool(r <= self.inside * (1 + SDP_RTOL) + certificate_tol(np.linalg.cond(self.P)))

    def __call__(self, theta) -> np.ndarray | None:
        out = self.solve(theta)
        if out is None:
            return None
        c = self.core
        pi = make_physical(c.reg, out[0])
        if pi is None or not (physical_certificate(c.reg, pi, c.pi_nom, c.margin) and self.radius_ok(pi)):
            return None
        return pi


def reaches(reg, pi, theta) -> bool:
    """K pi = theta to rounding: |K pi - theta| <= certificate_tol(1) (|K| |pi| + |theta|) entrywise
    (the rounding of forming K pi and of one correction step; :func:`_reach`)."""
    from robust_drake.analysis.tolerance import certificate_tol

    K, pi, theta = np.asarray(reg.K, float), np.asarray(pi, float), np.asarray(theta, float)
    return bool(np.all(np.abs(K @ pi - theta) <= certificate_tol(1.0) * (np.abs(K) @ np.abs(pi) + np.abs(theta))))


class PhysicalBySdp:
    """pi with K pi = theta nearest to pi_nom in the weights W (masses and damping kept) with every
    body's pseudo-inertia >= margin D (D = diag(m r_g^2 (x3), m) of the URDF body, scaled as in
    :class:`_PhysicalProgram`) and every reflected rotor inertia >= 0: minimise ||y||^2 subject to
    K pi(y) = theta and the LMIs (a small SDP; Drake's Clarabel; built once, a call changes only the
    equality's bounds), then :func:`_reach` for K pi = theta to rounding. For arms whose null space
    of K is not made of whole unseen columns (a 3D arm: Ixx + Iyy of a link is seen only together
    with other links' entries), where :func:`make_physical` cannot repair a body. Calling it returns
    None when infeasible (theta is then no rigid-body arm with these masses) or when the certificate
    (:func:`physical_certificate`, :func:`reaches`) fails."""

    def __init__(self, reg, pi_nom, margin: float = 1e-4):
        self.core = c = _PhysicalProgram(reg, pi_nom, margin)
        c.prog.AddQuadraticCost(2.0 * np.eye(len(c.free)), np.zeros(len(c.free)), 0.0, c.y, is_convex=True)
        self.eq = c.prog.AddLinearEqualityConstraint(c.KS, np.zeros(len(c.K_nom)), c.y).evaluator()

    def solve(self, theta):
        """(pi, cost) of the SDP at theta without the certificate, or None."""
        rhs = np.asarray(theta, float) - self.core.K_nom
        self.eq.set_bounds(rhs, rhs)
        out = self.core.solve()
        return None if out is None else (self.core.pi(out[0]), out[1])

    def __call__(self, theta) -> np.ndarray | None:
        out = self.solve(theta)
        if out is None:
            return None
        c = self.core
        try:
            pi = make_physical(c.reg, _reach(c.reg, theta, out[0], c.w))
        except RobustDrakeError:
            return None
        if pi is None or not (physical_certificate(c.reg, pi, c.pi_nom, c.margin) and reaches(c.reg, pi, theta)):
            return None
        return pi


def _central_valid(Iv, m, h, tol=1e-12) -> bool:
    """Rotational inertia about the centre of mass PSD and triangle-valid (Iv about the origin)."""
    I = np.array([[Iv[0], Iv[3], Iv[4]], [Iv[3], Iv[1], Iv[5]], [Iv[4], Iv[5], Iv[2]]])
    c = h / m
    Ic = I - m * (c @ c * np.eye(3) - np.outer(c, c))
    lam = np.linalg.eigvalsh(0.5 * (Ic + Ic.T))
    scale = tol * max(abs(lam).max(), 1e-30)
    return bool(lam[0] >= -scale and lam[2] <= lam[0] + lam[1] + scale)


def _central_margin(Iv, m, h) -> bool:
    """:func:`_central_valid` with a relative margin of 1e-6 (Drake checks with its own tolerance)."""
    return _central_valid(Iv, m, h, tol=-1e-6)


def _round_xy(Iv, m, h):
    """Inertia entries (about the origin) whose central xy block is diag(a, a), a = max(Izz_c / 2
    (1 + 1e-3), its former mean): valid whenever Izz_c > 0 (the triangle inequality then holds)."""
    I = np.array([[Iv[0], Iv[3], Iv[4]], [Iv[3], Iv[1], Iv[5]], [Iv[4], Iv[5], Iv[2]]])
    c = h / m
    S = m * (c @ c * np.eye(3) - np.outer(c, c))
    Ic = I - S
    if Ic[2, 2] <= 0:
        return None
    a = max(0.5 * Ic[2, 2] * (1 + 1e-3), 0.5 * (Ic[0, 0] + Ic[1, 1]))
    Ic[0, 0] = Ic[1, 1] = a
    Ic[0, 1] = Ic[1, 0] = 0.0
    Io = Ic + S
    return np.array([Io[0, 0], Io[1, 1], Io[2, 2], Io[0, 1], Io[0, 2], Io[1, 2]])


def make_physical(reg, pi) -> np.ndarray | None:
    """pi with every body's central inertia valid, changing only inertia entries K does not see:
    where Ixx, Iyy, Ixy are all unseen (a planar arm turning about z) the central xy block is made
    round (:func:`_round_xy`); otherwise the unseen diagonal entries are raised by the same
    smallest amount (bisection). None if that cannot make the body valid (e.g. Izz about the centre
    of mass <= 0: the drawn first moments and Izz are not a rigid body) or a reflected rotor
    inertia is negative."""
    pi = np.array(pi, float)
    unseen = np.all(np.abs(np.asarray(reg.K, float)) < 1e-12, axis=0)
    for k in range(len(reg._nodes)):
        m, h, Iv = pi[10 * k], pi[10 * k + 1:10 * k + 4], pi[10 * k + 4:10 * k + 10].copy()
        if m <= 0 or _central_valid(Iv, m, h):
            continue
        free = unseen[10 * k + 4:10 * k + 10]
        if free[0] and free[1] and free[3]:
            new = _round_xy(Iv, m, h)
            if new is None or not _central_margin(new, m, h):
                return None
            pi[10 * k + 4:10 * k + 10] = new
            continue
        up = np.zeros(6)
        up[:3] = free[:3]
        top = 10.0 * (abs(Iv).max() + m * h @ h / m ** 2)
        if not up.any() or not _central_margin(Iv + top * up, m, h):
            return None
        lo, hi = 0.0, top
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if _central_margin(Iv + mid * up, m, h) else (mid, hi)
        pi[10 * k + 4:10 * k + 10] = Iv + hi * up
    base = 10 * len(reg._nodes)
    for c, (_, kind, _) in enumerate(reg._extras):
        if kind == "Ia" and pi[base + c] < 0:
            return None
    return pi


def plant_setup(reg, pi):
    """``setup(plant, context)`` writing pi into a plant built from the regressor's URDF."""
    from pydrake.multibody.tree import SpatialInertia, UnitInertia

    bodies = [nd.body.name() for nd in reg._nodes]
    extras = list(reg._extras)
    base = 10 * len(bodies)

    def setup(plant, ctx):
        for k, name in enumerate(bodies):
            m, h, Iv = pi[10 * k], pi[10 * k + 1:10 * k + 4], pi[10 * k + 4:10 * k + 10]
            if m <= 0:
                continue
            G = UnitInertia(*(Iv / m))  # about the body origin: Ixx, Iyy, Izz, Ixy, Ixz, Iyz
            plant.GetBodyByName(name).SetSpatialInertiaInBodyFrame(ctx, SpatialInertia(m, h / m, G))
        for c, (ename, kind, _) in enumerate(extras):
            if kind != "Ia":
                continue
            jname = ename.split("_", 1)[1]
            for a in plant.GetJointActuatorIndices():
                act = plant.get_joint_actuator(a)
                if act.joint().name() == jname:
                    act.SetRotorInertia(ctx, pi[base + c] / act.gear_ratio(ctx) ** 2)
    return setup


def _z(rng, p, kind):
    d = rng.standard_normal(p)
    d /= np.linalg.norm(d)
    return d if kind == "boundary" else d * rng.uniform() ** (1.0 / p)


def _realise(reg, theta, pi_nom, sdp):
    """Standard parameters of a rigid-body arm with base parameters theta, or None: the closed-form
    nearest point (:func:`standard_for_base`, :func:`make_physical`), else the SDP. A theta the
    closed form cannot reach with the masses kept (the weighted normal equations lose it to
    rounding, seen on serial7's larger sandwich-covariance sets) goes to the SDP as well."""
    try:
        pi = make_physical(reg, standard_for_base(reg, theta, pi_nom))
    except RobustDrakeError:
        pi = None
    return sdp(theta) if pi is None else pi


def draw_plants(reg, theta0, P, count: int, rng, boundary_share: float = 0.5, tries: int = 20):
    """``count`` :class:`PlantDraw` across E(P, theta0): the first round(boundary_share count) on
    its boundary, the rest inside; returns (draws, rejected).

    A draw no rigid body with the URDF's masses realises is drawn again (counted in ``rejected``);
    after ``tries`` such draws the last one is replaced by the nearest physically valid point of
    the set (:class:`NearestPhysical`, ``PlantDraw.projected``; its radius is then below 1; a
    projection whose solve or certificate fails is counted and another draw projected). Where
    most of the set is no rigid body (a 3D arm's poorly excited link inertias) this keeps the draws
    spread over the part of the set a real arm can be in."""
    from robust_drake.models import make_plant
    from robust_drake.uncertainty.confidence import mahalanobis_radius
    from robust_drake.uncertainty.ellipsoid import Ellipsoid

    theta0, P = np.asarray(theta0, float), np.asarray(P, float)
    E = Ellipsoid(theta0, P).E
    pi_nom = reg.standard_parameters()
    n_b = int(round(boundary_share * count))
    out, rejected, sdp, nearest = [], 0, PhysicalBySdp(reg, pi_nom), None
    plant = make_plant(reg.urdf)
    for i in range(count):
        kind, projected = ("boundary" if i < n_b else "interior"), False
        for _ in range(tries):
            theta = theta0 + E @ _z(rng, len(theta0), kind)
            pi = _realise(reg, theta, pi_nom, sdp)
            if pi is not None:
                break
            rejected += 1
        else:
            nearest, projected = nearest or NearestPhysical(reg, pi_nom, theta0, P), True
            for _ in range(tries):  # a failed solve or certificate: project another draw
                pi = nearest(theta)
                if pi is not None:
                    break
                rejected += 1
                theta = theta0 + E @ _z(rng, len(theta0), kind)
            else:
                raise RobustDrakeError(f"no physically valid plant near {2 * tries} {kind} draws of the set")
            theta = np.asarray(reg.K, float) @ pi
        setup = plant_setup(reg, pi)
        ctx = plant.CreateDefaultContext()
        setup(plant, ctx)
        th_drake = reg.base_parameters(plant, ctx)
        if not np.allclose(th_drake, theta, rtol=1e-8, atol=1e-10 * max(np.abs(theta).max(), 1.0)):
            raise RobustDrakeError("a drawn plant does not have the drawn base parameters (internal error)")
        out.append(PlantDraw(theta=th_drake, radius=mahalanobis_radius(theta0, P, th_drake), kind=kind, pi=pi,
                             setup=setup, projected=projected))
    return out, rejected
