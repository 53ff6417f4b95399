"""Inverse-dynamics regressors: closed forms from the papers and Drake-derived ones.

Closed forms (pure numpy, vectorised over leading axes):

- :func:`d2r2_regressor` -- Jaritz & Spong eq. 15, ``Y(q, qd, v, a) theta = M(q) a + C(q, qd) v``
  with theta of eq. 14 (see :mod:`robust_drake.models` for the D2R2 parameter sets).
- :func:`imi_scara_regressor` -- Calafiore & Indri section 5, ``tau = D(q, qd, qdd) theta``,
  theta in R^8 (4 inertial + Coulomb and viscous friction of eq. 16).  The printed entry
  D_{1,2} has ``s2 qdd2 (2 qd1 + qd2)``; the physics (and Drake) give ``s2 qd2 (2 qd1 + qd2)``,
  which is what is implemented (see BUILD_NOTES.md, "Models and regressors").
- :data:`IMI_THETA0` and :data:`IMI_P`: the published central estimate and confidence-ellipsoid
  matrix (CI section 5.1) live in this module.

General (:class:`InverseDynamicsRegressor`), for any URDF with revolute/prismatic/weld joints
on a fixed base: ``tau = Y(q, v, vdot) theta_base`` including gravity, with the *standard*
parameters per moving body ``[m, m cx, m cy, m cz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` (centre of
mass and rotational inertia about the **body origin**, in the body frame), plus the reflected
rotor inertia ``Ia_<joint>`` (kr^2 Ir) where the URDF has one and a viscous coefficient
``b_<joint>`` where it has joint damping.  The identifiable base set is found numerically (QR
on random samples, columns scanned in a fixed priority order); ``base_from_standard`` is the
linear map theta_base = K pi.

Two routes give the same base parameterisation:

- ``"numeric"``: a vectorised recursive Newton-Euler regressor in numpy (Featherstone's spatial
  algebra, joint geometry read from the Drake plant); cost grows ~ n^2 and a 7-link chain
  derives in well under a second.
- ``"symbolic"``: ``MultibodyPlant.ToSymbolic()``, symbolic spatial inertias (m, c, unit inertia
  about the body origin), ``CalcInverseDynamics`` with ``CalcForceElementsContribution``
  (gravity), ``DecomposeLumpedParameters``, and the lumped regressor compiled to one vectorised
  numpy function.  Only sensible for short chains (pitfalls notes: ~20x slower per link).

``method="auto"`` uses symbolic for n <= 2 and numeric otherwise.  The numeric route evaluates
few samples (<= 64, e.g. one controller tick) with a batched world-frame algorithm
(``_standard_world``) and many with the body-frame recursion (``_standard_numeric_recursive``);
both give the same matrix (tested).

Slotine-Li regressor (:meth:`InverseDynamicsRegressor.slotine_li`, per tick
:meth:`~InverseDynamicsRegressor.slotine_li_single`): ``Y(q, qd, v, a) theta_base = M(q) a +
C(q, qd) v + g(q)`` with the same theta_base, by polarisation of the velocity products
(C(q, qd) v = 1/4 [h(q, qd + v) - h(q, qd - v)], h(q, w) = C(q, w) w): JS eq. 15 for any arm.
"""

from __future__ import annotations

import math
import os
import pathlib
import threading
import time
from dataclasses import dataclass

import numpy as np

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError

__all__ = [
    "IMI_L1",
    "IMI_L2",
    "IMI_THETA0",
    "IMI_P",
    "IMI_THETA_NAMES",
    "d2r2_regressor",
    "imi_scara_regressor",
    "imi_theta_from_plant",
    "InverseDynamicsRegressor",
    "drake_inverse_dynamics",
    "clear_cache",
    "PinocchioSlotineLi",
]

#: rank cut of every fit: singular values below RANK_TOL * s_max (unit-norm columns) count as
#: directions the data do not identify (least squares, folds, URDF comparison, effect aliases)
RANK_TOL = 1e-6

# ----------------------------------------------------------------------------- closed forms


def d2r2_regressor(q, qd, v, a) -> np.ndarray:
    """JS eq. 15: Y(q, qd, v, a), shape (..., 2, 3), with Y theta = M(q) a + C(q, qd) v.

    theta = [m1 lc1^2 + m2 l1^2 + I1, m2 lc2^2 + I2, m2 l1 lc2] (eq. 14);
    y13 = cos q2 (2 a1 + a2) - sin q2 (qd1 v2 + qd2 (v1 + v2)), y23 = cos q2 a1 + sin q2 qd1 v1.
    With v = qd and a = qdd this is the inverse dynamics (horizontal plane, no gravity).
    """
    q, qd, v, a = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (q, qd, v, a)))
    if q.shape[-1] != 2:
        raise RobustDrakeError(f"d2r2_regressor expects 2 joints (last axis 2), got {q.shape}")
    c2, s2 = np.cos(q[..., 1]), np.sin(q[..., 1])
    a1, a2 = a[..., 0], a[..., 1]
    qd1, qd2 = qd[..., 0], qd[..., 1]
    v1, v2 = v[..., 0], v[..., 1]
    Y = np.zeros(q.shape[:-1] + (2, 3))
    Y[..., 0, 0] = a1
    Y[..., 0, 1] = a1 + a2
    Y[..., 0, 2] = c2 * (2.0 * a1 + a2) - s2 * (qd1 * v2 + qd2 * (v1 + v2))
    Y[..., 1, 1] = a1 + a2
    Y[..., 1, 2] = c2 * a1 + s2 * qd1 * v1
    return Y


_IMI = packaged_description("imi_scara")  # robots/imi_scara.yaml, the one source of these numbers
IMI_L1, IMI_L2 = _IMI.link_lengths  # m, CI section 5
#: CI section 5.1 central estimate: [Gamma1z + m2 l1^2, m2 s2x, m2 s2y, Gamma2z,
#: sigma_s1, sigma_v1, sigma_s2, sigma_v2] (SI units).
IMI_THETA0 = np.array(_IMI.parameter_sets["theta0"])
IMI_THETA_NAMES = (
    "Gamma1z+m2*l1^2", "m2*s2x", "m2*s2y", "Gamma2z", "sigma_s1", "sigma_v1", "sigma_s2", "sigma_v2",
)
#: CI section 5.1 confidence-ellipsoid matrix, E(P, theta0) = {theta: (theta - theta0)^T P^-1
#: (theta - theta0) <= 1}, as printed (symmetric, positive definite: min eigenvalue 0.019).
IMI_P = np.array([
    [1.62, 2.84, 1.56, 0.1, -1.13, 4.03, -0.13, 0.06],
    [2.84, 9.06, 5.31, 0.19, -1.38, 2.75, -0.38, -0.08],
    [1.56, 5.31, 3.95, 0.05, -0.57, 0.39, -0.11, -0.49],
    [0.1, 0.19, 0.05, 0.03, -0.06, 0.22, -0.02, 0.04],
    [-1.13, -1.38, -0.57, -0.06, 3.66, -9.49, 0.07, -0.08],
    [4.03, 2.75, 0.39, 0.22, -9.49, 32.2, -0.22, 0.56],
    [-0.13, -0.38, -0.11, -0.02, 0.07, -0.22, 0.26, -0.32],
    [0.06, -0.08, -0.49, 0.04, -0.08, 0.56, -0.32, 0.74],
])


def imi_scara_regressor(q, qd, qdd, l1: float = IMI_L1) -> np.ndarray:
    """CI section 5: D(q, qd, qdd), shape (..., 2, 8), tau = D theta (horizontal plane).

    Columns 1-4 rigid body, 5-8 friction of eq. 16 (sgn(qd_i), qd_i per joint).
    Correction of the printed D_{1,2}: ``l1 (c2 (2 qdd1 + qdd2) - s2 qd2 (2 qd1 + qd2))``
    (the paper prints ``qdd2`` in the centripetal/Coriolis product).
    """
    q, qd, qdd = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (q, qd, qdd)))
    if q.shape[-1] != 2:
        raise RobustDrakeError(f"imi_scara_regressor expects 2 joints (last axis 2), got {q.shape}")
    c2, s2 = np.cos(q[..., 1]), np.sin(q[..., 1])
    qd1, qd2 = qd[..., 0], qd[..., 1]
    a1, a2 = qdd[..., 0], qdd[..., 1]
    D = np.zeros(q.shape[:-1] + (2, 8))
    D[..., 0, 0] = a1
    D[..., 0, 1] = l1 * (c2 * (2 * a1 + a2) - s2 * qd2 * (2 * qd1 + qd2))
    D[..., 0, 2] = l1 * (-s2 * (2 * a1 + a2) - c2 * qd2 * (2 * qd1 + qd2))
    D[..., 0, 3] = a1 + a2
    D[..., 0, 4] = np.sign(qd1)
    D[..., 0, 5] = qd1
    D[..., 1, 1] = l1 * (c2 * a1 + s2 * qd1**2)
    D[..., 1, 2] = l1 * (-s2 * a1 + c2 * qd1**2)
    D[..., 1, 3] = a1 + a2
    D[..., 1, 6] = np.sign(qd2)
    D[..., 1, 7] = qd2
    return D


def imi_theta_from_plant(plant, context=None) -> np.ndarray:
    """The 4 inertial entries of the CI theta (section 5) read from a 2-link horizontal plant.

    From the mass matrix: d22 = Gamma2z, d12(q2=0) = Gamma2z + l1 m2 s2x,
    d12(q2=pi/2) = Gamma2z - l1 m2 s2y, d11(0) = theta1 + Gamma2z + 2 l1 m2 s2x (theta1 includes
    any reflected rotor inertia on joint 1).  l1 is read from the plant.
    """
    from robust_drake.models import _joint2_offset

    if plant.num_positions() != 2:
        raise RobustDrakeError("imi_theta_from_plant expects a 2-joint arm")
    _, _, l1 = _joint2_offset(plant)
    ctx = plant.CreateDefaultContext() if context is None else context.Clone()
    plant.SetPositions(ctx, np.zeros(2))
    M0 = plant.CalcMassMatrix(ctx)
    plant.SetPositions(ctx, np.array([0.0, math.pi / 2]))
    M90 = plant.CalcMassMatrix(ctx)
    g2 = M0[1, 1]
    hx = (M0[0, 1] - g2) / l1
    hy = (g2 - M90[0, 1]) / l1
    th1 = M0[0, 0] - g2 - 2 * l1 * hx
    return np.array([th1, hx, hy, g2])


# ----------------------------------------------------------------------------- Drake reference


def drake_inverse_dynamics(plant, context, q, v, vdot) -> np.ndarray:
    """Drake's inverse dynamics INCLUDING gravity and force elements, vectorised by a loop.

    ``CalcInverseDynamics`` alone ignores gravity; force elements (gravity, joint damping) are
    added with ``CalcForceElementsContribution`` first.  Inputs (N, n) or (n,); output (N, n).
    """
    from pydrake.multibody.tree import MultibodyForces

    q, v, vdot = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, v, vdot))
    ctx = context.Clone()
    forces = MultibodyForces(plant)
    out = np.empty((q.shape[0], plant.num_velocities()))
    for k in range(q.shape[0]):
        plant.SetPositions(ctx, q[k])
        plant.SetVelocities(ctx, v[k])
        plant.CalcForceElementsContribution(ctx, forces)
        out[k] = plant.CalcInverseDynamics(ctx, vdot[k], forces)
    return out


# ----------------------------------------------------------------------------- spatial helpers


_EYE3 = np.eye(3)


def _skew(w):
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -w[..., 2], w[..., 1]
    S[..., 1, 0], S[..., 1, 2] = w[..., 2], -w[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -w[..., 1], w[..., 0]
    return S


def _rot_axis(axis, angle):
    """Rodrigues: (N,) angles about a fixed unit axis -> (N, 3, 3)."""
    k = np.asarray(axis, dtype=float)
    K = _skew(k)
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _motion_transform(R_PB, p_PB):
    """Featherstone's BX_P from the pose of B in P: (N,3,3), (N,3) -> (N,6,6)."""
    E = np.swapaxes(R_PB, -1, -2)
    X = np.zeros(R_PB.shape[:-2] + (6, 6))
    X[..., :3, :3] = E
    X[..., 3:, 3:] = E
    X[..., 3:, :3] = -E @ _skew(p_PB)
    return X


def _cross(a, b):
    """a x b for (..., 3) arrays (np.cross costs ~25 us per call on small arrays, this ~5 us)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))  # filled in place: np.stack costs more
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


def _crm_times(vel, m):
    """crm(vel) m for spatial motion vectors (..., 6)."""
    w, vl = vel[..., :3], vel[..., 3:]
    mw, mv = m[..., :3], m[..., 3:]
    return np.concatenate([_cross(w, mw), _cross(w, mv) + _cross(vl, mw)], axis=-1)


def _body_force_regressor(vel, acc):
    """K(v, a), (N, 6, 10): f = I a + v x* I v = K pi, pi = [m, hx, hy, hz, Ixx, Iyy, Izz, Ixy,
    Ixz, Iyz] (h = m c, I about the body origin)."""
    N = vel.shape[0]
    w, vl = vel[:, :3], vel[:, 3:]
    al, av = acc[:, :3], acc[:, 3:]

    def L(x):  # I x = L(x) [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]
        out = np.zeros((x.shape[0], 3, 6))
        out[:, 0, 0], out[:, 0, 3], out[:, 0, 4] = x[:, 0], x[:, 1], x[:, 2]
        out[:, 1, 1], out[:, 1, 3], out[:, 1, 5] = x[:, 1], x[:, 0], x[:, 2]
        out[:, 2, 2], out[:, 2, 4], out[:, 2, 5] = x[:, 2], x[:, 0], x[:, 1]
        return out

    Sw, Sv, Sa, Sal = _skew(w), _skew(vl), _skew(av), _skew(al)
    K = np.zeros((N, 6, 10))
    K[:, :3, 4:] = L(al) + Sw @ L(w)
    K[:, :3, 1:4] = -Sa - Sw @ Sv + Sv @ Sw
    K[:, 3:, 0] = av + _cross(w, vl)
    K[:, 3:, 1:4] = Sal + Sw @ Sw
    return K


#: samples per block of :meth:`InverseDynamicsRegressor.evaluate` / ``torque`` for large N
EVALUATE_ROWS = 4096

_STD_SUFFIX = ("m", "mx", "my", "mz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
# Priority when choosing which standard column represents a group (earlier = kept):
# joint-axis inertias before masses (the classical regrouping into ZZ_j), base-side bodies first.
_PRIORITY = {"Izz": 0, "Iyy": 1, "Ixx": 2, "Ixy": 3, "Ixz": 4, "Iyz": 5, "mx": 6, "my": 7, "mz": 8, "m": 9}


@dataclass
class _Node:
    body: object
    joint: object
    parent: int  # index into nodes, -1 = world (or a body welded to it)
    R_WP: np.ndarray  # orientation of the parent body in world (used when parent == -1)
    kind: str  # "revolute", "prismatic", "weld"
    X_PF: object
    X_BM: object
    X_FM: object  # for welds
    axis: np.ndarray  # joint axis in F (= M)
    S: np.ndarray  # (6,) motion subspace in B coordinates
    qi: int
    vi: int


class InverseDynamicsRegressor:
    """Regressor ``tau = Y(q, v, vdot) theta_base`` (gravity included) derived from a URDF.

    Build with :meth:`from_robot` (cached per (urdf, load, method)).  Attributes: ``n``,
    ``standard_names``, ``base_names``, ``method`` ("symbolic" or "numeric"), ``K``
    (theta_base = K pi), ``base_index`` (standard columns kept), ``derivation_time`` (s).
    """

    def __init__(self, plant, method: str = "auto", *, urdf: str = "", load: str = "none",
                 rank_tol: float = 1e-9, seed: int = 0):
        t0 = time.perf_counter()
        self.plant = plant
        self.urdf = urdf
        self.load = load
        self.n = plant.num_velocities()
        if plant.num_positions() != self.n:
            raise RobustDrakeError("only arms with one position per velocity (no quaternions) are supported")
        if method == "auto":
            method = "symbolic" if self.n <= 2 else "numeric"
        if method not in ("symbolic", "numeric"):
            raise RobustDrakeError(f"unknown regressor method {method!r}: use 'auto', 'symbolic' or 'numeric'")
        self.method = method
        self._fast_local = threading.local()  # per-thread PinocchioSlotineLi of slotine_li_single
        self._context = plant.CreateDefaultContext()
        self._build_tree()
        self._build_extras()
        self.standard_names = tuple(
            f"{s}_{nd.body.name()}" for nd in self._nodes for s in _STD_SUFFIX
        ) + tuple(name for name, _, _ in self._extras)
        self.p_standard = len(self.standard_names)
        if method == "symbolic":
            self._build_symbolic()
        self._find_base_set(rank_tol, seed)
        self.derivation_time = time.perf_counter() - t0

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_robot(cls, robot_or_urdf, load: str = "none", method: str = "auto") -> "InverseDynamicsRegressor":
        """Regressor of a robot name in ``robust_drake.models.ROBOTS`` or a ``.urdf`` path."""
        from robust_drake.models import make_plant, resolve_urdf

        path = resolve_urdf(robot_or_urdf, load)
        key = (str(path), os.path.getmtime(path), method)  # the path already encodes the load
        with _CACHE_LOCK:
            hit = _CACHE.get(key)
        if hit is not None:
            return hit
        plant = make_plant(str(path))
        reg = cls(plant, method, urdf=str(path), load=load)
        with _CACHE_LOCK:
            _CACHE[key] = reg
        return reg

    def _build_tree(self):
        from pydrake.multibody.tree import JointIndex

        plant = self.plant
        world = plant.world_body().index()
        fixed = {b.index() for b in plant.GetBodiesWeldedTo(plant.world_body())}
        inboard = {}
        for i in range(plant.num_joints()):
            j = plant.get_joint(JointIndex(i))
            inboard[j.child_body().index()] = j
        nodes, pos = [], {}
        ctx0 = plant.CreateDefaultContext()  # poses of bodies welded to the world do not depend on q

        def visit(bidx):
            if bidx in pos or bidx in fixed:
                return pos.get(bidx, -1)
            j = inboard.get(bidx)
            if j is None:
                raise RobustDrakeError(f"body {plant.get_body(bidx).name()} has no inboard joint (floating base?)")
            parent = visit(j.parent_body().index())
            tname = j.type_name()
            if tname == "revolute":
                kind = "revolute"
            elif tname == "prismatic":
                kind = "prismatic"
            elif tname == "weld":
                kind = "weld"
            else:
                raise RobustDrakeError(
                    f"joint {j.name()} of type {tname!r} is not supported (revolute, prismatic, weld)"
                )
            X_PF = j.frame_on_parent().GetFixedPoseInBodyFrame()
            X_BM = j.frame_on_child().GetFixedPoseInBodyFrame()
            axis = np.zeros(3)
            S = np.zeros(6)
            X_FM = None
            qi = vi = -1
            if kind == "weld":
                X_FM = j.X_FM()
            else:
                axis = np.asarray(j.revolute_axis() if kind == "revolute" else j.translation_axis(), float)
                axis = axis / np.linalg.norm(axis)
                R_BM = X_BM.rotation().matrix()
                a_B = R_BM @ axis
                if kind == "revolute":
                    S[:3] = a_B
                    S[3:] = np.cross(X_BM.translation(), a_B)
                else:
                    S[3:] = a_B
                qi, vi = j.position_start(), j.velocity_start()
            R_WP = plant.EvalBodyPoseInWorld(ctx0, j.parent_body()).rotation().matrix()
            nodes.append(_Node(plant.get_body(bidx), j, parent, R_WP, kind, X_PF, X_BM, X_FM, axis, S, qi, vi))
            pos[bidx] = len(nodes) - 1
            return pos[bidx]

        for b in range(plant.num_bodies()):
            from pydrake.multibody.tree import BodyIndex

            bidx = BodyIndex(b)
            if bidx != world:
                visit(bidx)
        self._nodes = nodes
        self._moving_joints = [nd for nd in nodes if nd.kind != "weld"]
        if len(self._moving_joints) != self.n:
            raise RobustDrakeError("every velocity must belong to a revolute or prismatic joint")

    def _build_extras(self):
        """Reflected rotor inertia and joint damping columns where the URDF has them."""
        from pydrake.multibody.tree import JointActuatorIndex

        plant, ctx = self.plant, self._context
        extras = []  # (name, kind "Ia"/"b", velocity index)
        for i in range(plant.num_actuators()):
            act = plant.get_joint_actuator(JointActuatorIndex(i))
            if act.default_reflected_inertia() != 0.0:
                extras.append((f"Ia_{act.joint().name()}", "Ia", act.joint().velocity_start()))
        for nd in self._moving_joints:
            if np.any(nd.joint.default_damping_vector() != 0.0):
                extras.append((f"b_{nd.joint.name()}", "b", nd.vi))
        self._extras = extras
        self._ctx_for_params = ctx

    # ------------------------------------------------------------------ standard regressor (numeric)
    def _standard_numeric(self, q, v, vd):
        """Standard regressor (N, n, p_standard) of the numeric route: the batched world-frame
        evaluation for few samples (the per-tick path: ~3x fewer numpy calls), the recursion for
        many (its small-matrix products scale better with N; crossover measured between 3 and 3000
        samples on serial7, see BUILD_NOTES)."""
        if q.shape[0] <= 64:
            return self._standard_world(q, v, vd)
        return self._standard_numeric_recursive(q, v, vd)

    def _standard_numeric_recursive(self, q, v, vd):
        """Recursive Newton-Euler regressor in body coordinates (Featherstone), the reference
        the batched :meth:`_standard_world` is tested against."""
        N = q.shape[0]
        nodes = self._nodes
        g = self.plant.gravity_field().gravity_vector()
        g = np.asarray(g, dtype=float)
        vel, acc, X = [None] * len(nodes), [None] * len(nodes), [None] * len(nodes)
        consts = self._node_constants()
        for k, nd in enumerate(nodes):
            R_PF, p_PF, R_MB, p_MB, R_FMw, p_FMw = consts[k]
            if nd.kind == "weld":
                R_FM = np.broadcast_to(R_FMw, (N, 3, 3))
                p_FM = np.broadcast_to(p_FMw, (N, 3))
            elif nd.kind == "revolute":
                R_FM = _rot_axis(nd.axis, q[:, nd.qi])
                p_FM = np.zeros((N, 3))
            else:
                R_FM = np.broadcast_to(np.eye(3), (N, 3, 3))
                p_FM = q[:, nd.qi, None] * nd.axis
            R_PM = R_PF @ R_FM
            p_PM = p_PF + p_FM @ R_PF.T
            R_PB = R_PM @ R_MB
            p_PB = p_PM + R_PM @ p_MB
            Xk = _motion_transform(R_PB, p_PB)
            X[k] = Xk
            if nd.parent < 0:  # parent fixed to the world: v = 0, a = -gravity, in the parent's frame
                aP = np.zeros((N, 6, 1))
                aP[:, 3:, 0] = -(nd.R_WP.T @ g)
                vk = np.zeros((N, 6))
            else:
                aP = acc[nd.parent][:, :, None]
                vk = (Xk @ vel[nd.parent][:, :, None])[:, :, 0]
            ak = (Xk @ aP)[:, :, 0]
            if nd.kind != "weld":
                qd, qdd = v[:, nd.vi], vd[:, nd.vi]
                vJ = qd[:, None] * nd.S
                vk = vk + vJ
                ak = ak + qdd[:, None] * nd.S + _crm_times(vk, vJ)
            vel[k], acc[k] = vk, ak
        p = self.p_standard
        nb = len(nodes)
        # F[k]: regressor of the total spatial force transmitted by body k's joint, in k's frame.
        # Nodes are in topological order (children after parents), so body k's subtree only
        # involves standard columns 10 k .. 10 nb: F[k] stores just those.
        F = [np.zeros((N, 6, 10 * (nb - k))) for k in range(nb)]
        for k in range(nb):
            F[k][:, :, :10] = _body_force_regressor(vel[k], acc[k])
        Y = np.zeros((N, self.n, p))
        for k in range(nb - 1, -1, -1):
            nd = nodes[k]
            if nd.kind != "weld":
                Y[:, nd.vi, 10 * k:10 * nb] = np.matmul(nd.S, F[k])
            if nd.parent >= 0:
                off = 10 * (k - nd.parent)
                F[nd.parent][:, :, off:] += np.matmul(np.swapaxes(X[k], 1, 2), F[k])
        self._add_extras(Y, v, vd)
        return Y

    def _node_constants(self):
        """Per node (R_PF, p_PF, R_MB, p_MB, R_FM, p_FM of welds) as numpy arrays, read once
        from the Drake frames (pydrake accessors cost microseconds per call)."""
        c = getattr(self, "_consts", None)
        if c is None:
            c = []
            for nd in self._nodes:
                R_BM, p_BM = nd.X_BM.rotation().matrix(), nd.X_BM.translation()
                R_MB = R_BM.T.copy()
                weld = nd.kind == "weld"
                c.append((nd.X_PF.rotation().matrix().copy(), nd.X_PF.translation().copy(), R_MB, -R_MB @ p_BM,
                          nd.X_FM.rotation().matrix().copy() if weld else None,
                          nd.X_FM.translation().copy() if weld else None))
            self._consts = c
        return c

    # ------------------------------------------------------------------ standard regressor (world frame)
    def _world_constants(self):
        """Constants of :meth:`_standard_world`.

        Per node, the pose of the body in its parent, X_PB(q) = X_PF X_FM(q) X_MB, is written
        as constants times (1, sin q, 1 - cos q) for revolute joints (Rodrigues:
        R_FM = I + s K + (1 - c) K^2), (1, q) for prismatic ones, constant for welds; for nodes
        whose parent is welded to the world the parent's world pose is folded in, so their
        parent is the world (index nb).  ``support[k, i]`` = 1 when joint i's child body is
        node k or one of its ancestors."""
        c = getattr(self, "_wconsts", None)
        if c is not None:
            return c
        nodes = self._nodes
        nb = len(nodes)
        ctx0 = self.plant.CreateDefaultContext()
        consts = self._node_constants()
        R0 = np.zeros((nb, 3, 3))
        R1 = np.zeros((nb, 3, 3))
        R2 = np.zeros((nb, 3, 3))
        p0 = np.zeros((nb, 3))
        p1 = np.zeros((nb, 3))
        p2 = np.zeros((nb, 3))
        a_P = np.zeros((nb, 3))  # joint axis in the parent (world for roots)
        pF_P = np.zeros((nb, 3))  # joint frame origin in the parent (world for roots)
        parent = np.zeros(nb, dtype=int)
        for k, nd in enumerate(nodes):
            R_PF, p_PF, R_MB, p_MB, R_FMw, p_FMw = consts[k]
            if nd.parent < 0:
                X = self.plant.EvalBodyPoseInWorld(ctx0, nd.joint.parent_body())
                R_WP, p_WP = X.rotation().matrix(), X.translation()
                R_PF, p_PF = R_WP @ R_PF, p_WP + R_WP @ p_PF
                parent[k] = nb
            else:
                parent[k] = nd.parent
            if nd.kind == "weld":
                R0[k] = R_PF @ R_FMw @ R_MB
                p0[k] = p_PF + R_PF @ (p_FMw + R_FMw @ p_MB)
            elif nd.kind == "revolute":
                Kx = _skew(nd.axis)
                R0[k], R1[k], R2[k] = R_PF @ R_MB, R_PF @ Kx @ R_MB, R_PF @ Kx @ Kx @ R_MB
                p0[k], p1[k], p2[k] = p_PF + R_PF @ p_MB, R_PF @ Kx @ p_MB, R_PF @ Kx @ Kx @ p_MB
            else:
                R0[k] = R_PF @ R_MB
                p0[k], p1[k] = p_PF + R_PF @ p_MB, R_PF @ nd.axis
            a_P[k] = R_PF @ nd.axis if nd.kind != "weld" else 0.0
            pF_P[k] = p_PF
        joints = [k for k, nd in enumerate(nodes) if nd.kind != "weld"]
        jpos = {k: i for i, k in enumerate(joints)}
        nj = len(joints)
        support = np.zeros((nb, nj))
        for k in range(nb):
            a = k
            while a >= 0:
                if a in jpos:
                    support[k, jpos[a]] = 1.0
                a = nodes[a].parent
        J = np.array(joints, dtype=int)
        rev = np.array([nodes[k].kind == "revolute" for k in joints], dtype=bool)
        c = {"R0": R0, "R1": R1[J[rev]], "R2": R2[J[rev]], "p0": p0, "p1r": p1[J[rev]], "p2r": p2[J[rev]],
             "p1p": p1[J[~rev]], "rev_nodes": J[rev], "pri_nodes": J[~rev],
             "rev_q": np.array([nodes[k].qi for k in J[rev]], dtype=int),
             "pri_q": np.array([nodes[k].qi for k in J[~rev]], dtype=int),
             "parent": parent, "joints": J, "joint_parent": parent[J], "a_P": a_P[J], "pF_P": pF_P[J],
             "revolute": rev, "support": support, "vi": np.array([nodes[k].vi for k in joints], dtype=int),
             "topo": [(k, int(parent[k])) for k in range(nb)],
             "g": np.asarray(self.plant.gravity_field().gravity_vector(), dtype=float).copy()}
        self._wconsts = c
        return c

    def _standard_world(self, q, v, vd):
        """The standard regressor (N, n, p_standard) with every body's motion in world (Plucker,
        world-origin) coordinates, batched over bodies: the parent-to-body poses of all joints in
        one Rodrigues expression, forward kinematics as the only loop over the tree (two small
        products per body), then V = sum of S_j qd_j over supporting joints, A = -g + sum(S_j
        qdd_j + V_j x S_j qd_j), the body regressors K(v_B, a_B) of all bodies in one call,
        forces to world coordinates and tau_j = S_j^T (sum over supported bodies).  Same result
        as the recursive Newton-Euler of :meth:`_standard_numeric_recursive` (tested)."""
        N = q.shape[0]
        nb = len(self._nodes)
        wc = self._world_constants()
        # parent-to-body poses of every node, (N, nb, 3, 3) and (N, nb, 3)
        R_PB = np.repeat(wc["R0"][None], N, axis=0)
        p_PB = np.repeat(wc["p0"][None], N, axis=0)
        rn = wc["rev_nodes"]
        if rn.size:
            ang = q[:, wc["rev_q"]]
            s, c1 = np.sin(ang), 1.0 - np.cos(ang)
            R_PB[:, rn] += s[..., None, None] * wc["R1"] + c1[..., None, None] * wc["R2"]
            p_PB[:, rn] += s[..., None] * wc["p1r"] + c1[..., None] * wc["p2r"]
        pn = wc["pri_nodes"]
        if pn.size:
            p_PB[:, pn] += q[:, wc["pri_q"], None] * wc["p1p"]
        # world poses; slot nb is the world itself
        R_W = np.empty((N, nb + 1, 3, 3))
        p_W = np.empty((N, nb + 1, 3))
        R_W[:, nb] = _EYE3
        p_W[:, nb] = 0.0
        for k, par in wc["topo"]:
            Rp = R_W[:, par]
            R_W[:, k] = Rp @ R_PB[:, k]
            p_W[:, k] = p_W[:, par] + (Rp @ p_PB[:, k, :, None])[..., 0]
        R_WB, p_WB = R_W[:, :nb], p_W[:, :nb]
        # joint motion subspaces in world-origin Plucker coordinates
        jp = wc["joint_parent"]
        Rj = R_W[:, jp]
        a_W = (Rj @ wc["a_P"][..., None])[..., 0]
        pF = p_W[:, jp] + (Rj @ wc["pF_P"][..., None])[..., 0]
        nj = jp.size
        S = np.zeros((N, nj, 6))
        rev = wc["revolute"]
        S[:, rev, :3] = a_W[:, rev]
        S[:, rev, 3:] = _cross(pF[:, rev], a_W[:, rev])
        S[:, ~rev, 3:] = a_W[:, ~rev]
        sup = wc["support"]  # (nb, nj)
        qd = v[:, wc["vi"]]
        qdd = vd[:, wc["vi"]]
        Sqd = S * qd[..., None]
        V = sup @ Sqd  # (N, nb, 6)
        c_j = S * qdd[..., None] + _crm_times(V[:, wc["joints"]], Sqd)
        A = sup @ c_j
        A[:, :, 3:] -= wc["g"]
        # to body coordinates: w_B = R^T w, v_B = R^T (v_O + w x p)
        RT = np.swapaxes(R_WB, -1, -2)
        VA = np.concatenate([V, A], axis=1)  # (N, 2 nb, 6)
        RT2 = np.concatenate([RT, RT], axis=1)
        p2 = np.concatenate([p_WB, p_WB], axis=1)
        w, vo = VA[..., :3], VA[..., 3:]
        B = np.concatenate([(RT2 @ w[..., None])[..., 0], (RT2 @ (vo + _cross(w, p2))[..., None])[..., 0]], axis=-1)
        Kb = _body_force_regressor(B[:, :nb].reshape(N * nb, 6), B[:, nb:].reshape(N * nb, 6)).reshape(N, nb, 6, 10)
        # forces to world coordinates: f_W = R f_B, n_O = R n_B + p x (R f_B)
        Rf = R_WB @ Kb[:, :, 3:, :]
        Rn = R_WB @ Kb[:, :, :3, :] + _skew(p_WB) @ Rf
        G = np.concatenate([Rn, Rf], axis=2)  # (N, nb, 6, 10)
        T = (S[:, None, :, :] @ G) * sup[None, :, :, None]  # (N, nb, nj, 10)
        Y = np.zeros((N, self.n, self.p_standard))
        Y[:, wc["vi"], :10 * nb] = np.swapaxes(T, 1, 2).reshape(N, nj, 10 * nb)
        self._add_extras(Y, v, vd)
        return Y

    def _add_extras(self, Y, v, vd):
        base = 10 * len(self._nodes)
        for c, (_, kind, vi) in enumerate(self._extras):
            Y[:, vi, base + c] = vd[:, vi] if kind == "Ia" else v[:, vi]

    # ------------------------------------------------------------------ symbolic route
    def _build_symbolic(self):
        from pydrake.multibody.tree import (
            JointActuatorIndex,
            MultibodyForces_,
            SpatialInertia_,
            UnitInertia_,
        )
        from pydrake.symbolic import DecomposeLumpedParameters, Expression, MakeVectorVariable, Variable

        t0 = time.perf_counter()
        plant_s = self.plant.ToSymbolic()
        ctx = plant_s.CreateDefaultContext()
        n = self.n
        qv = MakeVectorVariable(n, "q")
        vv = MakeVectorVariable(n, "v")
        av = MakeVectorVariable(n, "vd")
        params = []
        self._sym_param_vars = []  # per node: (m, c[3], G[6])
        for nd in self._nodes:
            b = plant_s.get_body(nd.body.index())
            nm = nd.body.name()
            m = Variable(f"m_{nm}")
            c = [Variable(f"c{ax}_{nm}") for ax in "xyz"]
            G = [Variable(f"G{s}_{nm}") for s in ("xx", "yy", "zz", "xy", "xz", "yz")]
            M = SpatialInertia_[Expression](
                Expression(m), np.array([Expression(x) for x in c]),
                UnitInertia_[Expression](*[Expression(x) for x in G]), skip_validity_check=True,
            )
            b.SetSpatialInertiaInBodyFrame(ctx, M)
            self._sym_param_vars.append((m, c, G))
            params += [m] + c + G
        for i in range(plant_s.num_actuators()):  # reflected inertia: columns added analytically
            plant_s.get_joint_actuator(JointActuatorIndex(i)).SetRotorInertia(ctx, Expression(0.0))
        for nd in self._moving_joints:  # damping: columns added analytically
            plant_s.get_joint(nd.joint.index()).SetDampingVector(ctx, np.zeros(1))
        plant_s.SetPositions(ctx, np.array([Expression(x) for x in qv]))
        plant_s.SetVelocities(ctx, np.array([Expression(x) for x in vv]))
        forces = MultibodyForces_[Expression](plant_s)
        plant_s.CalcForceElementsContribution(ctx, forces)
        tau = plant_s.CalcInverseDynamics(ctx, np.array([Expression(x) for x in av]), forces)
        W, alpha, w0 = DecomposeLumpedParameters(tau, np.array(params))
        from pydrake.symbolic import ExpressionKind

        for e in np.asarray(w0).ravel():
            if not (e.get_kind() == ExpressionKind.Constant and abs(e.Evaluate()) < 1e-12):
                raise RobustDrakeError(f"inverse dynamics has a parameter-free term {e}; not supported")
        self._sym_time = time.perf_counter() - t0
        self._W_expr, self._sym_qva = np.asarray(W), (list(qv), list(vv), list(av))
        self._W_fun = _compile_matrix(self._W_expr, {"q": list(qv), "v": list(vv), "vd": list(av)})
        self._W_scalar = _compile_matrix(self._W_expr, {"q": list(qv), "v": list(vv), "vd": list(av)}, scalar=True)
        self._alpha = np.asarray(alpha).ravel()
        self._params_vars = params
        self._A = self._alpha_linear_map()

    def _alpha_linear_map(self):
        """alpha (lumped parameters) = A pi (rigid-body standard parameters), found exactly by
        evaluating alpha at m = pi_m, c = h/m, G = I/m for a valid point and unit steps."""
        nb = len(self._nodes)
        rng = np.random.default_rng(1)

        def alpha_at(pi):
            env = {}
            for k, (m, c, G) in enumerate(self._sym_param_vars):
                blk = pi[10 * k:10 * k + 10]
                env[m] = blk[0]
                for j in range(3):
                    env[c[j]] = blk[1 + j] / blk[0]
                for j in range(6):
                    env[G[j]] = blk[4 + j] / blk[0]
            return np.array([a.Evaluate(env) for a in self._alpha])

        pi0 = np.zeros(10 * nb)
        for k in range(nb):
            pi0[10 * k:10 * k + 10] = [1.0 + k, 0.1, 0.2, 0.3, 2.0, 2.1, 2.2, 0.01, 0.02, 0.03]
        f0 = alpha_at(pi0)
        A = np.zeros((len(self._alpha), 10 * nb))
        for j in range(10 * nb):
            e = pi0.copy()
            e[j] += 1.0
            A[:, j] = alpha_at(e) - f0
        # alpha must be linear in pi (parameterisation by unit inertia about the body origin)
        pr = pi0 * (1.0 + 0.5 * rng.random(pi0.size))
        if not np.allclose(alpha_at(pr), A @ pr, rtol=1e-9, atol=1e-12):
            raise RobustDrakeError("lumped parameters are not linear in the standard parameters")
        return A

    def _standard_symbolic(self, q, v, vd):
        W = self._W_fun(q, v, vd)  # (N, n, k)
        N = q.shape[0]
        Y = np.zeros((N, self.n, self.p_standard))
        Y[:, :, :10 * len(self._nodes)] = W @ self._A
        self._add_extras(Y, v, vd)
        return Y

    # ------------------------------------------------------------------ base set
    def _find_base_set(self, rank_tol, seed):
        rng = np.random.default_rng(seed)
        p = self.p_standard
        N = max(40, 3 * p // max(self.n, 1) + 10)
        q = rng.uniform(-math.pi, math.pi, (N, self.n))
        v = rng.normal(0, 2.0, (N, self.n))
        vd = rng.normal(0, 5.0, (N, self.n))
        Y = self._standard_numeric(q, v, vd).reshape(N * self.n, p)
        order = sorted(range(p), key=self._priority)
        norms = np.linalg.norm(Y, axis=0)
        scale = np.where(norms > 0, norms, 1.0)
        Yo = (Y / scale)[:, order]
        nonzero = norms[order] > 1e-12 * max(norms.max(), 1.0)
        Yo = Yo[:, nonzero]
        cols = np.array(order)[nonzero]
        from scipy.linalg import qr

        R = qr(Yo, mode="r")[0]
        d = np.abs(np.diag(R))
        keep = np.sort(cols[d > rank_tol * max(d.max(), 1.0)])
        drop = np.array([j for j in range(p) if j not in set(keep)], dtype=int)
        Yb = Y[:, keep]
        beta = np.zeros((len(keep), len(drop)))
        if len(drop):
            beta = np.linalg.lstsq(Yb, Y[:, drop], rcond=None)[0]
            beta[np.abs(beta) < 1e-10] = 0.0
            resid = np.linalg.norm(Yb @ beta - Y[:, drop]) / max(np.linalg.norm(Y), 1.0)
            if resid > 1e-8:
                raise RobustDrakeError(f"base-set reduction failed (residual {resid:.2e})")
        K = np.zeros((len(keep), p))
        K[np.arange(len(keep)), keep] = 1.0
        if len(drop):
            K[:, drop] = beta
        self.base_index = keep
        self.K = K
        self.p_base = len(keep)
        self.base_names = tuple(_combo_name(K[i], self.standard_names) for i in range(len(keep)))

    def _priority(self, j):
        nb = len(self._nodes)
        if j >= 10 * nb:
            return (2, 0, j)
        k, s = divmod(j, 10)
        return (0, _PRIORITY[_STD_SUFFIX[s]], k)

    # ------------------------------------------------------------------ public API
    @staticmethod
    def _inputs(q, v, vdot, n):
        arrs = [np.asarray(x, dtype=float) for x in (q, v, vdot)]
        arrs = [a[None, :] if a.ndim == 1 else a for a in arrs]
        if any(a.ndim != 2 or a.shape[1] != n for a in arrs) or len({a.shape[0] for a in arrs}) != 1:
            raise RobustDrakeError(f"q, v, vdot must have shape (N, {n}) or ({n},) and equal N")
        return arrs

    def _standard_rows(self, q, v, vd, columns=None):
        """Standard regressor of checked (N, n) arrays, restricted to ``columns`` when given,
        evaluated in blocks of ``EVALUATE_ROWS`` samples for large N (the recursion's temporaries
        grow with N: ~20 kB per sample of serial7, 2 GB at 10^5 samples at once). Every sample is
        computed on its own by the same route (the recursion for N > 64), so the values do not
        depend on the blocking."""
        N = q.shape[0]
        if self.method == "symbolic":
            f = self._standard_symbolic
        else:
            f = self._standard_world if N <= 64 else self._standard_numeric_recursive
        if N <= EVALUATE_ROWS:
            Y = f(q, v, vd)
            return Y if columns is None else Y[:, :, columns]
        p = self.p_standard if columns is None else len(columns)
        out = np.empty((N, self.n, p))
        for a in range(0, N, EVALUATE_ROWS):
            r = slice(a, a + EVALUATE_ROWS)
            if r.stop < N < r.stop + 65:  # no short tail (<= 64 rows would switch route)
                r = slice(a, N)
            Y = f(q[r], v[r], vd[r])
            out[r] = Y if columns is None else Y[:, :, columns]
            if r.stop == N:
                break
        return out

    def evaluate_standard(self, q, v, vdot) -> np.ndarray:
        """Regressor for the standard parameters, (N, n, p_standard)."""
        q, v, vd = self._inputs(q, v, vdot, self.n)
        return self._standard_rows(q, v, vd)

    def evaluate(self, q, v, vdot) -> np.ndarray:
        """Base regressor Y, (N, n, p_base): tau = Y @ theta_base (gravity included)."""
        q, v, vd = self._inputs(q, v, vdot, self.n)
        return self._standard_rows(q, v, vd, self.base_index)

    # ------------------------------------------------------------------ Slotine-Li regressor
    def _slotine_li_std(self, q, qd, v, a) -> np.ndarray:
        """Standard-parameter Slotine-Li regressor for checked (N, n) arrays, (N, n, p_standard).

        Polarisation of the velocity-product term: with C from the Christoffel symbols,
        C(q, qd) v is symmetric bilinear in (qd, v), so with h(q, w) = C(q, w) w (the
        velocity-product part of inverse dynamics)

            C(q, qd) v = 1/4 [h(q, qd + v) - h(q, qd - v)].

        In regressor form: Y_SL = Y(q, 0, a) + 1/4 [Y(q, qd + v, 0) - Y(q, qd - v, 0)];
        Y(q, 0, a) carries M(q) a + g(q) (and the reflected-inertia columns Ia_j a_j), the
        gravity columns cancel in the difference.  Joint damping acts on the true velocity:
        its columns b_j are set to qd_j (the difference would give v_j / 2).
        """
        N, n = q.shape
        z = np.zeros((N, n))
        Q = np.concatenate([q, q, q])
        W = np.concatenate([z, qd + v, qd - v])
        A = np.concatenate([a, z, z])
        Ys = self._standard_symbolic(Q, W, A) if self.method == "symbolic" else self._standard_numeric(Q, W, A)
        Y = Ys[:N] + 0.25 * (Ys[N:2 * N] - Ys[2 * N:])
        base = 10 * len(self._nodes)
        for c, (_, kind, vi) in enumerate(self._extras):
            if kind == "b":
                Y[:, vi, base + c] = qd[:, vi]
        return Y

    def slotine_li(self, q, qd, v, a) -> np.ndarray:
        """Slotine-Li regressor Y(q, qd, v, a), (N, n, p_base), for the base parameters of
        :meth:`evaluate` (same theta_base):

            Y(q, qd, v, a) theta_base = M(q) a + C(q, qd) v + g(q)  [+ Ia_j a_j + b_j qd_j]

        (JS eq. 15 generalised to any URDF arm; C from Christoffel symbols, so M' - 2C is skew,
        JS eq. 6).  Inputs (N, n) or (n,): positions [rad or m], velocity qd, reference
        velocity v, reference acceleration a (SI).  With v = qd, a = qdd it is :meth:`evaluate`.
        """
        q, qd, v, a = self._inputs4(q, qd, v, a)
        return self._slotine_li_std(q, qd, v, a)[:, :, self.base_index]

    def slotine_li_single(self, q, qd, v, a) -> np.ndarray:
        """One sample of :meth:`slotine_li`, (n, p_base), for the per-tick controller path:
        inputs are length-n sequences and are not checked (use :meth:`slotine_li` elsewhere).

        Evaluated by :class:`PinocchioSlotineLi` (two Pinocchio joint-torque regressor calls and
        one product with the base map; one instance per thread); the numpy/symbolic routes of
        :meth:`slotine_li_single_reference` are its test reference."""
        fast = getattr(self._fast_local, "f", None)
        if fast is None:
            fast = self._fast_local.f = PinocchioSlotineLi(self)
        return fast(q, qd, v, a)

    def slotine_li_fast(self) -> "PinocchioSlotineLi":
        """A new :class:`PinocchioSlotineLi` of this regressor (its own Pinocchio data), for a
        controller that owns its per-tick regressor."""
        return PinocchioSlotineLi(self)

    def slotine_li_single_reference(self, q, qd, v, a) -> np.ndarray:
        """:meth:`slotine_li_single` by this regressor's own route (numpy world-frame recursion or
        the compiled symbolic regressor): the reference the Pinocchio path is tested against."""
        n = self.n
        if self.method == "symbolic":
            return self._slotine_li_single_symbolic(q, qd, v, a)
        f = np.asarray
        Y = self._slotine_li_std(f(q, float).reshape(1, n), f(qd, float).reshape(1, n),
                                 f(v, float).reshape(1, n), f(a, float).reshape(1, n))
        return Y[0][:, self.base_index]

    # ------------------------------------------------------------------ Pinocchio twin of the tree
    def pinocchio_model(self):
        """(model, joint_q, T): a Pinocchio model of the same kinematic tree (one joint per moving
        Drake joint, frames read from the Drake plant at q = 0, bodies welded to a moving body folded
        into its joint), ``joint_q[j]`` the Drake position/velocity index of Pinocchio joint j + 1,
        and T (10 n_joints, 10 n_bodies) with Y_standard[:, :10 n_bodies] = Y_pinocchio T, Y_pinocchio
        Pinocchio's joint-torque regressor (rows permuted to Drake's order), whose per-joint
        parameters are [m, m c, Ixx, Ixy, Iyy, Ixz, Iyz, Izz] about the joint frame's origin."""
        c = self.__dict__.get("_pin")
        if c is not None:
            return c
        import pinocchio as pin
        from pydrake.math import RigidTransform

        plant, nodes = self.plant, self._nodes
        ctx = plant.CreateDefaultContext()
        plant.SetPositions(ctx, np.zeros(self.n))
        model = pin.Model()
        model.gravity.linear = np.asarray(plant.gravity_field().gravity_vector(), dtype=float).copy()
        jid, X_WJ, owner, joint_q = {}, {}, {}, []
        for k, nd in enumerate(nodes):
            a = nd.parent  # the nearest moving ancestor (-1: the world or a body welded to it)
            while a >= 0 and nodes[a].kind == "weld":
                a = nodes[a].parent
            if nd.kind == "weld":
                owner[k] = a
                continue
            X_WM = plant.EvalBodyPoseInWorld(ctx, nd.body).multiply(nd.X_BM)  # = X_WF at q = 0
            X_WP = RigidTransform() if a < 0 else X_WJ[a]
            X_PM = X_WP.inverse().multiply(X_WM)
            ax = [float(x) for x in nd.axis]
            jm = pin.JointModelRevoluteUnaligned(*ax) if nd.kind == "revolute" else pin.JointModelPrismaticUnaligned(*ax)
            j = model.addJoint(0 if a < 0 else jid[a], jm,
                               pin.SE3(X_PM.rotation().matrix().copy(), X_PM.translation().copy()), nd.joint.name())
            model.appendBodyToJoint(j, pin.Inertia.Identity(), pin.SE3.Identity())  # inertia unused
            jid[k], X_WJ[k], owner[k] = j, X_WM, k
            joint_q.append(nd.qi)
        if any(o < 0 for o in owner.values()):
            raise RobustDrakeError("a moving body without a moving joint above it")
        nj = len(jid)
        T = np.zeros((10 * nj, 10 * len(nodes)))
        for k, nd in enumerate(nodes):
            o = owner[k]
            X = X_WJ[o].inverse().multiply(plant.EvalBodyPoseInWorld(ctx, nd.body))
            J = jid[o] - 1
            T[10 * J:10 * J + 10, 10 * k:10 * k + 10] = _pinocchio_parameter_map(X.rotation().matrix(), X.translation())
        c = self._pin = (model, np.array(joint_q, dtype=int), T)
        return c

    def _slotine_li_single_symbolic(self, q, qd, v, a):
        """Symbolic route, one sample: the compiled lumped regressor in scalar math at the three
        polarisation states, combined in the lumped space (linear), then mapped by alpha = A pi."""
        n = self.n
        q, qd, v, a = (list(map(float, x)) for x in (q, qd, v, a))
        z = [0.0] * n
        f = self._W_scalar
        W0 = np.array(f(q, z, a))
        Wp = np.array(f(q, [x + y for x, y in zip(qd, v)], z))
        Wm = np.array(f(q, [x - y for x, y in zip(qd, v)], z))
        Y = np.zeros((n, self.p_standard))
        Y[:, :10 * len(self._nodes)] = (W0 + 0.25 * (Wp - Wm)) @ self._A
        base = 10 * len(self._nodes)
        for c, (_, kind, vi) in enumerate(self._extras):
            Y[vi, base + c] = a[vi] if kind == "Ia" else qd[vi]
        return Y[:, self.base_index]

    def _inputs4(self, q, qd, v, a):
        arrs = [np.asarray(x, dtype=float) for x in (q, qd, v, a)]
        arrs = [x[None, :] if x.ndim == 1 else x for x in arrs]
        n = self.n
        if any(x.ndim != 2 or x.shape[1] != n for x in arrs) or len({x.shape[0] for x in arrs}) != 1:
            raise RobustDrakeError(f"q, qd, v, a must have shape (N, {n}) or ({n},) and equal N")
        return arrs

    def torque(self, q, v, vdot, theta_base=None) -> np.ndarray:
        """Inverse dynamics (N, n) from the regressor with theta_base (default: the URDF's),
        in blocks of ``EVALUATE_ROWS`` samples (no (N, n, p) array)."""
        th = self.base_parameters() if theta_base is None else np.asarray(theta_base, float)
        q, v, vd = self._inputs(q, v, vdot, self.n)
        N = q.shape[0]
        if N <= EVALUATE_ROWS:
            return self.evaluate(q, v, vd) @ th
        out = np.empty((N, self.n))
        for a in range(0, N, EVALUATE_ROWS):
            r = slice(a, a + EVALUATE_ROWS)
            if r.stop < N < r.stop + 65:
                r = slice(a, N)
            out[r] = self.evaluate(q[r], v[r], vd[r]) @ th
            if r.stop == N:
                break
        return out

    def standard_parameters(self, plant=None, context=None) -> np.ndarray:
        """pi: standard parameters read from ``context`` of ``plant`` (default: the URDF's values).

        Bodies and joints are matched by name, so any plant built from the same URDF works.
        """
        plant = self.plant if plant is None else plant
        ctx = plant.CreateDefaultContext() if context is None else context
        pi = np.zeros(self.p_standard)
        for k, nd in enumerate(self._nodes):
            b = nd.body if plant is self.plant else self._match_body(plant, nd.body)
            M = b.CalcSpatialInertiaInBodyFrame(ctx)
            m = M.get_mass()
            I = M.CalcRotationalInertia().CopyToFullMatrix3()
            pi[10 * k:10 * k + 10] = [m, *(m * M.get_com()), I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
        base = 10 * len(self._nodes)
        for c, (name, kind, _) in enumerate(self._extras):
            jname = name.split("_", 1)[1]
            joint = plant.GetJointByName(jname)
            if kind == "Ia":
                act = [plant.get_joint_actuator(a) for a in plant.GetJointActuatorIndices()
                       if plant.get_joint_actuator(a).joint().name() == jname][0]
                pi[base + c] = act.calc_reflected_inertia(ctx)
            else:
                pi[base + c] = float(joint.GetDampingVector(ctx)[0])
        return pi

    def _match_body(self, plant, body):
        """The body of ``plant`` with the same name (and model-instance name) as ``body``."""
        inst_name = self.plant.GetModelInstanceName(body.model_instance())
        if plant.HasModelInstanceNamed(inst_name):
            inst = plant.GetModelInstanceByName(inst_name)
            if plant.HasBodyNamed(body.name(), inst):
                return plant.GetBodyByName(body.name(), inst)
        if plant.HasBodyNamed(body.name()):
            return plant.GetBodyByName(body.name())
        raise RobustDrakeError(f"plant has no body named {body.name()!r}: not built from {self.urdf or 'this model'}")

    def __reduce__(self):
        # Drake plants do not pickle: rebuild from the URDF (e.g. in dask workers).
        if not self.urdf:
            raise TypeError("an InverseDynamicsRegressor built from a plant (not a URDF) cannot be pickled")
        return (InverseDynamicsRegressor.from_robot, (self.urdf, "none", self.method))

    def base_from_standard(self, pi) -> np.ndarray:
        """theta_base = K pi (works on (..., p_standard) arrays)."""
        return np.asarray(pi, dtype=float) @ self.K.T

    def base_parameters(self, plant=None, context=None) -> np.ndarray:
        """theta_base of the plant's (default: the URDF's) parameters."""
        return self.base_from_standard(self.standard_parameters(plant, context))

    def rank_report(self, q, v, vdot, tol: float = 1e-8) -> dict:
        """Identifiability of the base parameters from the samples (q, v, vdot).

        Returns ``{"rank", "p_base", "deficient", "condition", "unidentified"}`` where
        ``unidentified`` lists base parameter names whose columns are (numerically) dependent on
        the others for these samples.  ``deficient`` is True when rank < p_base.
        """
        Y = self.evaluate(q, v, vdot).reshape(-1, self.p_base)
        norms = np.linalg.norm(Y, axis=0)
        Ys = Y / np.where(norms > 0, norms, 1.0)
        s = np.linalg.svd(Ys, compute_uv=False)
        rank = int(np.sum(s > tol * max(s[0], 1e-300))) if s.size else 0
        from scipy.linalg import qr

        _, R, piv = qr(Ys, mode="economic", pivoting=True)
        d = np.abs(np.diag(R))
        dep = [self.base_names[piv[i]] for i in range(len(d)) if d[i] <= tol * max(d[0], 1e-300)]
        dep += [self.base_names[piv[i]] for i in range(len(d), self.p_base)]
        cond = float(s[0] / s[-1]) if s.size and s[-1] > 0 else float("inf")
        return {"rank": rank, "p_base": self.p_base, "deficient": rank < self.p_base,
                "condition": cond, "unidentified": dep}

    def __repr__(self):
        return (f"InverseDynamicsRegressor({pathlib.Path(self.urdf).name or 'plant'}, n={self.n}, "
                f"p_standard={self.p_standard}, p_base={self.p_base}, method={self.method!r})")


def _pinocchio_parameter_map(R, p) -> np.ndarray:
    """10 x 10 linear map from the standard parameters of a body B, [m, m c, Ixx, Iyy, Izz, Ixy, Ixz,
    Iyz] (c and I about B's origin, in B), to Pinocchio's of the same mass in a frame J with X_JB =
    (R, p): [m, m c_J, I_J xx, xy, yy, xz, yz, zz], I_J about J's origin in J.  With h = m c:
    h_J = R h + m p and I_J = R I R^T - m [p]^2 - [p][R h] - [R h][p] (parallel axes, linear in
    (m, h, I))."""
    out = np.zeros((10, 10))
    for col in range(10):
        e = np.zeros(10)
        e[col] = 1.0
        m, h = e[0], e[1:4]
        I = np.array([[e[4], e[7], e[8]], [e[7], e[5], e[9]], [e[8], e[9], e[6]]])
        Rh = R @ h
        P, H = _skew(p), _skew(Rh)
        IJ = R @ I @ R.T - m * P @ P - P @ H - H @ P
        out[:, col] = [m, *(Rh + m * p), IJ[0, 0], IJ[0, 1], IJ[1, 1], IJ[0, 2], IJ[1, 2], IJ[2, 2]]
    return out


class PinocchioSlotineLi:
    """Y(q, qd, v, a) theta_base = M(q) a + C(q, qd) v + g(q) [+ Ia_j a_j + b_j qd_j] for one sample,
    the same matrix as :meth:`InverseDynamicsRegressor.slotine_li` (tested on every URDF), from two
    calls of Pinocchio's ``computeJointTorqueRegressor`` on a twin of the Drake tree
    (:meth:`InverseDynamicsRegressor.pinocchio_model`).

    With h(q, w) = C(q, w) w quadratic in w, polarisation gives C(q, qd) v = h(q, w+) - h(q, w-)
    for w+- = (qd +- v) / 2, so

        Y = Y_g(q, w+, a) - Y_0(q, w-, 0),

    Y_g the regressor with gravity (M a + h + g) and Y_0 the same tree without gravity (h alone);
    then Y_base = Y_pin T_base (T_base: the columns of :meth:`pinocchio_model`'s T that the base set
    keeps) and the reflected-inertia / damping columns set to a_j and qd_j.  Inputs: length-n
    sequences (q [rad or m], qd, v [per s], a [per s^2]); returns an (n, p_base) array."""

    def __init__(self, reg: "InverseDynamicsRegressor"):
        import pinocchio as pin

        model, joint_q, T = reg.pinocchio_model()
        self.n, self.p_base = reg.n, reg.p_base
        self._f = pin.computeJointTorqueRegressor
        self._mg, self._dg = model, model.createData()
        m0 = model.copy()
        m0.gravity.linear = np.zeros(3)
        self._m0, self._d0 = m0, m0.createData()
        self._perm = None if np.array_equal(joint_q, np.arange(reg.n)) else joint_q
        nr = T.shape[1]
        keep = np.asarray(reg.base_index)
        rigid = keep < nr
        Tb = np.zeros((T.shape[0], reg.p_base))
        Tb[:, rigid] = T[:, keep[rigid]]
        self._Tb = Tb
        ex = {c: e for c, e in enumerate(reg._extras)}
        self._ia = [(int(b), ex[k - nr][2]) for b, k in enumerate(keep) if k >= nr and ex[k - nr][1] == "Ia"]
        self._b = [(int(b), ex[k - nr][2]) for b, k in enumerate(keep) if k >= nr and ex[k - nr][1] == "b"]
        self._zero = np.zeros(reg.n)

    def __call__(self, q, qd, v, a) -> np.ndarray:
        q, qd, v, a = (np.asarray(x, dtype=float) for x in (q, qd, v, a))
        wp, wm = 0.5 * (qd + v), 0.5 * (qd - v)
        perm = self._perm
        if perm is None:
            D = self._f(self._mg, self._dg, q, wp, a) - self._f(self._m0, self._d0, q, wm, self._zero)
        else:
            D = np.empty((self.n, self._Tb.shape[0]))
            D[perm] = (self._f(self._mg, self._dg, q[perm], wp[perm], a[perm])
                       - self._f(self._m0, self._d0, q[perm], wm[perm], self._zero))
        Y = D @ self._Tb  # (a gather over Tb's few non-zeros measured slower than this product)
        for col, vi in self._ia:
            Y[vi, col] = a[vi]
        for col, vi in self._b:
            Y[vi, col] = qd[vi]
        return Y


def _combo_name(row, names):
    terms = []
    for j in np.flatnonzero(np.abs(row) > 1e-12):
        c = row[j]
        if abs(c - 1.0) < 1e-12:
            terms.append(names[j])
        else:
            terms.append(f"{c:.6g}*{names[j]}")
    return " + ".join(terms).replace("+ -", "- ")


_CACHE: dict = {}
_CACHE_LOCK = threading.Lock()


def clear_cache() -> None:
    """Forget cached regressors (e.g. after editing a URDF in place)."""
    with _CACHE_LOCK:
        _CACHE.clear()


# ----------------------------------------------------------------------------- expression compiler


def _compile_matrix(W, groups, scalar: bool = False):
    """Compile a matrix of pydrake Expressions in the variables ``groups`` ({"q": [Variable...],
    ...}) into ``f(q, v, vd) -> (N, rows, cols)``, one vectorised numpy function (common
    subexpressions shared).  ``scalar=True``: ``f(q, v, vd) -> rows x cols nested lists`` for one
    sample (sequences of floats), in ``math`` functions (no numpy call per operation)."""
    from pydrake.symbolic import ExpressionKind

    var_code = {}
    for g, vs in groups.items():
        for i, x in enumerate(vs):
            var_code[x.get_id()] = f"{g}[{i}]" if scalar else f"{g}[:, {i}]"
    lines, memo = [], {}
    unary = {
        ExpressionKind.Sin: "np.sin", ExpressionKind.Cos: "np.cos", ExpressionKind.Tan: "np.tan",
        ExpressionKind.Abs: "np.abs", ExpressionKind.Exp: "np.exp", ExpressionKind.Sqrt: "np.sqrt",
        ExpressionKind.Log: "np.log", ExpressionKind.Asin: "np.arcsin", ExpressionKind.Acos: "np.arccos",
        ExpressionKind.Atan: "np.arctan", ExpressionKind.Sinh: "np.sinh", ExpressionKind.Cosh: "np.cosh",
        ExpressionKind.Tanh: "np.tanh",
    }

    def emit(e):
        kind = e.get_kind()
        if kind == ExpressionKind.Constant:
            return repr(float(e.Evaluate()))
        if kind == ExpressionKind.Var:
            (x,) = list(e.GetVariables())
            return var_code[x.get_id()]
        key = e.to_string()
        if key in memo:
            return memo[key]
        _, args = e.Unapply()
        sub = [emit(a) if hasattr(a, "get_kind") else repr(float(a)) for a in args]
        if kind == ExpressionKind.Add:
            code = "(" + " + ".join(sub) + ")"
        elif kind == ExpressionKind.Mul:
            code = "(" + " * ".join(sub) + ")"
        elif kind == ExpressionKind.Div:
            code = f"({sub[0]} / {sub[1]})"
        elif kind == ExpressionKind.Pow:
            code = f"({sub[0]} ** {sub[1]})"
        elif kind in unary:
            code = f"{unary[kind]}({sub[0]})"
        elif kind == ExpressionKind.Atan2:
            code = f"{'math.atan2' if scalar else 'np.arctan2'}({sub[0]}, {sub[1]})"
        elif kind == ExpressionKind.Min:
            code = f"{'min' if scalar else 'np.minimum'}({sub[0]}, {sub[1]})"
        elif kind == ExpressionKind.Max:
            code = f"{'max' if scalar else 'np.maximum'}({sub[0]}, {sub[1]})"
        else:
            raise RobustDrakeError(f"cannot compile expression kind {kind}")
        name = f"t{len(memo)}"
        lines.append(f"    {name} = {code}")
        memo[key] = name
        return name

    if scalar:
        unary = {k: ("abs" if f == "np.abs" else f.replace("np.arc", "math.a").replace("np.", "math."))
                 for k, f in unary.items()}
    rows, cols = W.shape
    body = ["def _f(q, v, vd):"] if scalar else ["def _f(q, v, vd):", "    N = q.shape[0]"]
    assigns = []
    for i in range(rows):
        for j in range(cols):
            e = W[i, j]
            if e.get_kind() == ExpressionKind.Constant and e.Evaluate() == 0.0:
                continue
            assigns.append((f"    out[{i}][{j}] = " if scalar else f"    out[:, {i}, {j}] = ") + emit(e))
    alloc = (f"    out = [[0.0] * {cols} for _ in range({rows})]" if scalar
             else f"    out = np.zeros((N, {rows}, {cols}))")
    src = "\n".join(body + lines + [alloc] + assigns + ["    return out"])
    ns = {"np": np, "math": math}
    exec(compile(src, "<regressor>", "exec"), ns)
    f = ns["_f"]
    f.source = src
    return f
