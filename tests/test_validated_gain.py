"""The validated-gain rule for effects without a joint (a delay shared by all joints): judged on
every joint's validation rows pooled, each joint weighted by the reference model's error on it
(``stages.pooled_squared_errors``), so a gain on a light wrist counts as much as one on a heavy
shoulder, and a model that is no better on any joint is not a gain."""

from __future__ import annotations

import numpy as np

from robust_drake.model_repair import decisions as D
from robust_drake.model_repair.stages import pooled_squared_errors


def _residuals(seed, N=6000, scales=(30.0, 0.05), gain_on=None, gain=0.0):
    """Reference and new residuals of two joints with very different torque scales [N m]; the new
    model removes a share ``gain`` of joint ``gain_on``'s error (a structured part of it)."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / 500.0
    ref = np.empty((N, 2))
    new = np.empty((N, 2))
    for j, s in enumerate(scales):
        noise = rng.standard_normal(N) * s
        structure = s * np.sin(2 * np.pi * 0.7 * t + j)
        ref[:, j] = noise + structure
        new[:, j] = noise + structure * (1.0 - (gain if j == gain_on else 0.0))
    return ref, new


def _test(ref, new):
    ids = D.block_ids(np.zeros(len(ref), int), len(ref), 250)
    return D.paired_test(*pooled_squared_errors(ref, new), ids)


def test_a_gain_on_the_light_joint_alone_is_significant_when_pooled():
    ref, new = _residuals(1, gain_on=1, gain=0.8)
    t = _test(ref, new)
    assert t.better and t.estimate < -0.05  # (1 + 1.02 / 1.5) / 2 -> sqrt - 1 = -8.4 %
    # the same squared errors summed in N m^2 report it as no change: the shoulder's error is 600x larger
    raw = D.paired_test((ref ** 2).sum(axis=1), (new ** 2).sum(axis=1),
                        D.block_ids(np.zeros(len(ref), int), len(ref), 250))
    assert abs(raw.estimate) < 1e-5


def test_the_pooled_test_does_not_depend_on_a_joint_s_torque_unit():
    ref, new = _residuals(2, gain_on=0, gain=0.3)
    a = _test(ref, new)
    k = np.array([1.0, 1000.0])  # joint 2's torque logged in mN m
    b = _test(ref * k, new * k)
    assert np.isclose(a.estimate, b.estimate, rtol=1e-9) and np.isclose(a.p_better, b.p_better, rtol=1e-9)


def test_no_change_on_any_joint_is_not_called_a_gain_over_many_seeds():
    """With the new model equal to the reference up to noise (its own noise draw), the share of
    seeds called 'better' stays near the one-sided (1 - LEVEL) / 2."""
    calls = 0
    for seed in range(200):
        ref, _ = _residuals(seed)
        _, new = _residuals(10_000 + seed)
        calls += _test(ref, new).better
    assert calls / 200 <= (1 - D.LEVEL) / 2 + 3 * np.sqrt(0.025 * 0.975 / 200)
