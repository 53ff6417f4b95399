"""The paired block test of model_repair/decisions.py, calibrated on data it did not generate:
AR(1) error pairs from scipy's lfilter (correlated rows, as filtered residuals are), compared
with the rates the stated level promises."""

import numpy as np
import pytest
from scipy.signal import lfilter

from robust_drake.model_repair.decisions import (
    block_ids, block_length, compare_joints, holm, paired_test,
)


def _ar1(rng, N, phi):
    """Unit-variance AR(1) series, autocorrelation phi^k."""
    return lfilter([1.0], [1.0, -phi], rng.standard_normal(N)) * np.sqrt(1.0 - phi**2)


def _pair(seed, N=5000, phi=0.95, scale_new=1.0):
    """Two residual series that share a common part (the motion, the noise both models see) and
    differ by an independent part; ``scale_new`` scales the candidate's own part."""
    rng = np.random.default_rng(seed)
    common = _ar1(rng, N, phi)
    return common + 0.5 * _ar1(rng, N, phi), scale_new * (common + 0.5 * _ar1(rng, N, phi))


@pytest.mark.parametrize("phi", [0.9, 0.98])
def test_false_worse_and_false_better_rates_are_at_the_stated_level(phi):
    tr = -1.0 / np.log(phi)  # AR(1) correlation time [samples] at 1/e
    seeds = 300
    worse = better = 0
    for s in range(seeds):
        a, b = _pair(s, phi=phi)
        t = paired_test(a**2, b**2, block_ids(None, len(a), block_length(1.0, tr)))
        worse += t.worse
        better += t.better
    # one-sided 2.5 % each way; 300 seeds: binomial sd 0.9 %, so 5 % is > 2.5 sd above nominal
    assert worse / seeds <= 0.05 and better / seeds <= 0.05, (worse, better)


@pytest.mark.xfail(strict=True, reason="known (issue 21, decisions.py 'Known limit'): the ratio's delta-method "
                   "spread shrinks as R falls below 1, so 'better' comes 3-4x too often at the selection's levels")
def test_false_better_at_the_selection_levels_with_four_blocks():
    """The selection decides at one-sided alpha / 2 and alpha / 6 (1.25 % and 0.42 %) on the
    confirmation block of 10 s runs: 4 blocks. Null: two models whose errors have one distribution
    (a shared AR(1) part and each its own, correlation time 20 rows), blocks of 3 correlation
    times; 4000 pairs (binomial sd 0.18 % at 1.25 %), bound nominal + 3.5 sd."""
    phi, L, blocks, pairs = np.exp(-1.0 / 20.0), 60, 4, 4000
    ids = block_ids(None, blocks * L, L)
    rng = np.random.default_rng(7)
    p = np.empty(pairs)
    for k in range(pairs):
        common = _ar1(rng, blocks * L, phi)
        a, b = common + 0.7 * _ar1(rng, blocks * L, phi), common + 0.7 * _ar1(rng, blocks * L, phi)
        p[k] = paired_test(a**2, b**2, ids).p_better
    for alpha in (0.0125, 0.025 / 6):
        bound = alpha + 3.5 * np.sqrt(alpha * (1 - alpha) / pairs)
        assert np.mean(p < alpha) <= bound, (alpha, float(np.mean(p < alpha)))


def test_a_real_gain_is_detected_and_its_interval_covers_it():
    tr = -1.0 / np.log(0.95)
    hits = cover = 0
    for s in range(100):
        a, b = _pair(s, scale_new=0.85)  # 15 % lower RMS
        t = paired_test(a**2, b**2, block_ids(None, len(a), block_length(1.0, tr)))
        hits += t.better
        cover += t.low <= -0.15 <= t.high
        assert not t.worse
    assert hits >= 90 and cover >= 85, (hits, cover)


def test_holm_over_seven_null_joints_keeps_the_family_rate():
    tr = -1.0 / np.log(0.95)
    fam = single = 0
    for s in range(200):
        pairs = [_pair(1000 * s + j, N=3000) for j in range(7)]
        A = np.stack([p[0] for p in pairs], 1) ** 2
        B = np.stack([p[1] for p in pairs], 1) ** 2
        ids = block_ids(None, 3000, block_length(1.0, tr))
        tests = compare_joints(A, B, ids)
        fam += any(t.worse for t in tests)
        single += any(t.p_worse < 0.025 for t in tests)
    assert fam / 200 <= 0.05
    assert single > fam  # uncorrected, "some joint is worse" happens far more often


def test_holm_step_down():
    assert holm([0.001, 0.04, 0.2], 0.05) == [True, False, False]  # 0.04 > 0.05 / 2
    assert holm([0.01, 0.02, 0.03], 0.05) == [True, True, True]  # 0.01<.0167, 0.02<.025, 0.03<.05


def test_blocks_stay_inside_segments_and_masks():
    seg = np.repeat([0, 1], [25, 17])
    mask = np.ones(42, bool)
    mask[5] = False
    ids = block_ids(seg, 42, 10, mask)
    assert ids[5] == -1
    for b in np.unique(ids[ids >= 0]):
        assert len(np.unique(seg[ids == b])) == 1
    # segment 1: 17 rows -> one block of 10 and the 7-row tail (>= half a block) its own block
    assert len(np.unique(ids[seg == 1])) == 2


def test_too_few_blocks_decide_nothing():
    t = paired_test(np.ones(30), 4 * np.ones(30), block_ids(None, 30, 10))
    assert t.blocks == 3 and not t.worse and not t.better and np.isinf(t.high)
