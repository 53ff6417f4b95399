"""A smooth test motion for the identification tests: per joint, four harmonics of ``base_hz`` with
amplitudes N(0, 1)/k and uniform phases drawn from ``rng`` (joint by joint, harmonic by harmonic),
and its exact first and second derivatives."""

import numpy as np


def fourier_motion(t, rng, base_hz: float, n: int = 2, harmonics: int = 4):
    """(q, qd, qdd), each (len(t), n): q_j = sum_k a_jk sin(2 pi base_hz k t + ph_jk)."""
    N = len(t)
    q, qd, qdd = (np.zeros((N, n)) for _ in range(3))
    for j in range(n):
        for k in range(1, harmonics + 1):
            a, ph, w = rng.normal() / k, rng.uniform(0, 2 * np.pi), 2 * np.pi * base_hz * k
            q[:, j] += a * np.sin(w * t + ph)
            qd[:, j] += a * w * np.cos(w * t + ph)
            qdd[:, j] -= a * w * w * np.sin(w * t + ph)
    return q, qd, qdd
