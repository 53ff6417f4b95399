"""Planar 2-link kinematics (pure functions, vectorised over leading axes).

Used for the task-space error criteria (JS eqs. 58-59) and for the circle and
straight-line references given in Cartesian space (JS eqs. 50-51, BR section V).
Angles in rad, lengths in m; q2 is the elbow angle relative to link 1.
"""

from __future__ import annotations

import numpy as np

from robust_drake.errors import RobustDrakeError


def planar_forward_kinematics(q, link_lengths) -> np.ndarray:
    """Tool position (x, y) [m] of a planar 2-link arm; ``q`` has shape (..., 2)."""
    q = np.asarray(q, dtype=float)
    l1, l2 = float(link_lengths[0]), float(link_lengths[1])
    q1, q2 = q[..., 0], q[..., 1]
    x = l1 * np.cos(q1) + l2 * np.cos(q1 + q2)
    y = l1 * np.sin(q1) + l2 * np.sin(q1 + q2)
    return np.stack([x, y], axis=-1)


def planar_jacobian(q, link_lengths) -> np.ndarray:
    """Geometric Jacobian d(x, y)/dq, shape (..., 2, 2)."""
    q = np.asarray(q, dtype=float)
    l1, l2 = float(link_lengths[0]), float(link_lengths[1])
    q1, q2 = q[..., 0], q[..., 1]
    s1, c1 = np.sin(q1), np.cos(q1)
    s12, c12 = np.sin(q1 + q2), np.cos(q1 + q2)
    J = np.empty(q.shape[:-1] + (2, 2))
    J[..., 0, 0] = -l1 * s1 - l2 * s12
    J[..., 0, 1] = -l2 * s12
    J[..., 1, 0] = l1 * c1 + l2 * c12
    J[..., 1, 1] = l2 * c12
    return J


def planar_jacobian_dot(q, qd, link_lengths) -> np.ndarray:
    """Time derivative of :func:`planar_jacobian` along (q, qd)."""
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    l1, l2 = float(link_lengths[0]), float(link_lengths[1])
    q1, q2 = q[..., 0], q[..., 1]
    w1, w12 = qd[..., 0], qd[..., 0] + qd[..., 1]
    s1, c1 = np.sin(q1), np.cos(q1)
    s12, c12 = np.sin(q1 + q2), np.cos(q1 + q2)
    Jd = np.empty(q.shape[:-1] + (2, 2))
    Jd[..., 0, 0] = -l1 * c1 * w1 - l2 * c12 * w12
    Jd[..., 0, 1] = -l2 * c12 * w12
    Jd[..., 1, 0] = -l1 * s1 * w1 - l2 * s12 * w12
    Jd[..., 1, 1] = -l2 * s12 * w12
    return Jd


def planar_inverse_kinematics(p, link_lengths, elbow: str = "up") -> np.ndarray:
    """Joint angles reaching tool position ``p`` (..., 2).

    ``elbow='up'`` gives q2 > 0 (counter-clockwise elbow). Raises
    :class:`RobustDrakeError` if any point lies outside the annulus
    |l1 - l2| <= |p| <= l1 + l2 (an unreachable circle or line).
    """
    p = np.asarray(p, dtype=float)
    l1, l2 = float(link_lengths[0]), float(link_lengths[1])
    x, y = p[..., 0], p[..., 1]
    r2 = x * x + y * y
    c2 = (r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    if np.any(c2 > 1.0 + 1e-12) or np.any(c2 < -1.0 - 1e-12):
        r = np.sqrt(r2)
        raise RobustDrakeError(
            f"unreachable point(s): distance from the base spans [{r.min():.4f}, {r.max():.4f}] m, "
            f"but a 2-link arm with l1={l1} m, l2={l2} m reaches only [{abs(l1 - l2):.4f}, {l1 + l2:.4f}] m"
        )
    c2 = np.clip(c2, -1.0, 1.0)
    sign = 1.0 if elbow == "up" else -1.0
    q2 = sign * np.arccos(c2)
    q1 = np.arctan2(y, x) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    return np.stack([q1, q2], axis=-1)
