"""LFR algebra (CI eqs. 3, 4, 18): every operation against direct evaluation at random Delta."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from robust_drake.errors import RobustDrakeError
from robust_drake.uncertainty.lfr import LFR, lfr_from_affine, lfr_product, lfr_sum, random_deltas


def _affine(rng, a, b, N, rank=None):
    M0 = rng.normal(size=(a, b))
    C = []
    for _ in range(N):
        r = rank or rng.integers(0, min(a, b) + 1)
        C.append(rng.normal(size=(a, r)) @ rng.normal(size=(r, b)))
    return M0, np.array(C)


def _direct(M0, C, delta):
    return M0 + np.tensordot(delta, C, axes=1)


seeds = st.integers(0, 2**31 - 1)


@settings(max_examples=40, deadline=None)
@given(seed=seeds, a=st.integers(1, 4), b=st.integers(1, 4), N=st.integers(1, 5))
def test_affine_construction_matches_direct_sum_and_ranks(seed, a, b, N):
    rng = np.random.default_rng(seed)
    M0, C = _affine(rng, a, b, N)
    F = lfr_from_affine(M0, C)
    # eq. 18: r_i = rank(M_i)
    assert list(F.block_sizes()) == [np.linalg.matrix_rank(Ci) for Ci in C]
    for d in random_deltas(N, 6, rng):
        np.testing.assert_allclose(F.evaluate(d), _direct(M0, C, d), atol=1e-10)


@settings(max_examples=40, deadline=None)
@given(seed=seeds, a=st.integers(1, 4), b=st.integers(1, 4), c=st.integers(1, 4), N=st.integers(1, 4))
def test_product_sum_transpose_match_direct(seed, a, b, c, N):
    rng = np.random.default_rng(seed)
    A0, CA = _affine(rng, a, b, N)
    B0, CB = _affine(rng, b, c, N)
    E0, CE = _affine(rng, a, b, N)
    FA, FB, FE = lfr_from_affine(A0, CA), lfr_from_affine(B0, CB), lfr_from_affine(E0, CE)
    prod = lfr_product(FA, FB)
    # products of affine LFRs are structurally well posed (block-triangular H)
    assert prod.is_structurally_well_posed()
    # nested: (A B)^T (A B) uses a product whose factors already have H != 0
    gram = lfr_product(prod.transpose(), prod)
    s = lfr_sum(FA, FE)
    for d in random_deltas(N, 6, rng):
        A, B, E = _direct(A0, CA, d), _direct(B0, CB, d), _direct(E0, CE, d)
        np.testing.assert_allclose(prod.evaluate(d), A @ B, atol=1e-9)
        np.testing.assert_allclose(prod.transpose().evaluate(d), (A @ B).T, atol=1e-9)
        np.testing.assert_allclose(gram.evaluate(d), (A @ B).T @ (A @ B), atol=1e-7 * (1 + np.abs(A @ B).max() ** 2))
        np.testing.assert_allclose(s.evaluate(d), A + E, atol=1e-10)
        np.testing.assert_allclose(prod.reduce().evaluate(d), A @ B, atol=1e-9)


def test_product_of_affine_lfrs_is_quadratic_so_H_is_not_zero():
    """CI section 5 prints H^ = 0 for D^T D; with H = 0 the quadratic term is lost."""
    rng = np.random.default_rng(1)
    D0, CD = _affine(rng, 6, 3, 4, rank=1)
    F = lfr_from_affine(D0, CD)
    G = lfr_product(F.transpose(), F)
    assert np.abs(G.H).max() > 1e-3
    d = np.ones(4)
    D = _direct(D0, CD, d)
    wrong = LFR(G.M0, G.L, G.R, np.zeros_like(G.H), G.scalars, G.n_scalars)
    err_right = np.abs(G.evaluate(d) - D.T @ D).max()
    err_wrong = np.abs(wrong.evaluate(d) - D.T @ D).max()
    assert err_right < 1e-9 and err_wrong > 1e-2
    # the dropped term is exactly the quadratic one, sum_ij d_i d_j C_i^T C_j
    Q = sum(CD[i].T @ CD[j] for i in range(4) for j in range(4))
    np.testing.assert_allclose(err_wrong, np.abs(Q).max(), rtol=1e-9)


def test_well_posedness_is_checked_and_reported():
    # M(delta) = 1 / (1 - 2 delta): singular at delta = 0.5 (inside the box)
    F = LFR(np.zeros((1, 1)), [[1.0]], [[1.0]], [[2.0]], [0], 1)
    assert not F.is_structurally_well_posed()
    np.testing.assert_allclose(F.evaluate([0.25]), [[0.25 / (1 - 0.5)]])
    assert F.well_posedness_margin([0.5]) < 1e-12
    with pytest.raises(RobustDrakeError, match="not well posed"):
        F.evaluate([0.5])


def test_reduce_removes_dead_channels_only():
    rng = np.random.default_rng(3)
    D0, CD = _affine(rng, 4, 3, 3, rank=2)
    tau0 = rng.normal(size=(4, 1))
    M = lfr_from_affine(np.hstack([D0, tau0]), np.concatenate([CD, np.zeros((3, 4, 1))], axis=2))
    D = M.select(cols=slice(0, 3))
    G = lfr_product(D.transpose(), M)
    # a scalar acting only on tau has no channel in D^T: its p1 copy must vanish
    tau_only = lfr_from_affine(np.hstack([D0, tau0]), [np.hstack([np.zeros((4, 3)), rng.normal(size=(4, 1))])])
    Gt = lfr_product(tau_only.select(cols=slice(0, 3)).transpose(), tau_only)
    assert Gt.n_channels == 2 and Gt.reduce().n_channels == 1
    assert G.reduce().n_channels <= G.n_channels
    for d in random_deltas(3, 4, rng):
        np.testing.assert_allclose(G.reduce().evaluate(d), G.evaluate(d), atol=1e-9)
