"""Bascetta & Rocco section IV math: eq. 17 two ways, Lemmas 1-5, ||t||_inf two ways, bounds."""

import itertools

import numpy as np
import pytest
import scipy.linalg

from robust_drake.analysis import lemmas
from robust_drake.analysis.bascetta_bounds import (
    beta_case_a,
    beta_case_b,
    compute_bounds,
    gain_norm,
    sample_configurations,
)
from robust_drake.analysis.lyapunov import lyapunov_design
from robust_drake.analysis.norms import hinf_norm_hamiltonian, hinf_norm_lmi
from robust_drake.analysis.riccati import (
    are_residual,
    conditions16,
    design_riccati,
    eq17_data,
    gamma_max,
    solve_eq17,
)
from robust_drake.errors import RobustDrakeError, SolverError

# Grid over (kappa01, kappa02); (16) holds for some points and fails for others.
K01 = [1.5, 3.0, 8.0, 25.0, 120.0]
K02 = [1.0, 2.5, 4.0, 9.0]
GRID = list(itertools.product(K01, K02))
GOOD = [k for k in GRID if conditions16(*k)]
BAD = [k for k in GRID if not conditions16(*k)]


def t_closed_form(k01, k02, w):
    """t(jw) from BR Lemma 2 written out by hand: B^T A0 [sI - (A0+I)]^-1 B
    = -(k02 s + k01 - k02) / (s^2 + (k02 - 2) s + (k01 - k02 + 1))."""
    s = 1j * w
    return -(k02 * s + k01 - k02) / (s**2 + (k02 - 2) * s + (k01 - k02 + 1))


def test_grid_has_both_kinds():
    assert len(GOOD) >= 8 and len(BAD) >= 6


@pytest.mark.parametrize("k01,k02", GOOD)
def test_lemmas_hold_where_16_holds(k01, k02):
    gmax = gamma_max(k01, k02)
    gamma = 0.9 * gmax
    delta = 0.7
    c = lemmas.check_all(k01, k02, delta, gamma)
    assert all(c[f"lemma{i}"]["ok"] for i in range(1, 6)), c
    # Lemma 1: eig(calA + delta I) = delta * eig(A0 + I), all in the open left half plane
    n1 = c["lemma1"]["numbers"]
    assert n1["max_real_eig"] < 0 and n1["scaling_error"] < 1e-9
    # Lemma 2: Hamiltonian bisection, KYP LMI, MIMO T_delta and a dense sweep of the closed form agree
    n2 = c["lemma2"]["numbers"]
    w = np.logspace(-3, 3, 20001)
    k = np.argmax(np.abs(t_closed_form(k01, k02, w)))
    w_fine = np.linspace(w[max(k - 1, 0)], w[min(k + 1, len(w) - 1)], 20001)  # resolve sharp resonances
    sweep = max(np.max(np.abs(t_closed_form(k01, k02, w_fine))), np.max(np.abs(t_closed_form(k01, k02, w))))
    assert n2["t_norm_hamiltonian"] == pytest.approx(sweep, rel=1e-7)
    assert n2["t_norm_hamiltonian"] >= sweep * (1 - 1e-9)  # the sweep is a lower bound
    assert n2["t_norm_lmi"] == pytest.approx(n2["t_norm_hamiltonian"], rel=1e-5)
    assert n2["T_delta_norm"] == pytest.approx(n2["t_norm_hamiltonian"], rel=1e-8)
    # Lemma 5: eigenvalues of P0 above 1, stabilising
    n5 = c["lemma5"]["numbers"]
    assert min(n5["eig_P0"]) > 1.0 and n5["closed_loop_abscissa"] < 0
    # Lemma 4 from the 4x4 equation 18 solved directly
    assert c["lemma4"]["numbers"]["rel_diff"] < 1e-8


@pytest.mark.parametrize("k01,k02", BAD)
def test_lemmas_fail_where_16_fails(k01, k02):
    c = lemmas.check_all(k01, k02, 0.7, 0.3)
    # Lemma 1: some eigenvalue of A0 + I in the closed right half plane
    assert not c["lemma1"]["ok"] and c["lemma1"]["numbers"]["max_real_eig_A0_plus_I"] >= 0
    assert not c["lemma2"]["ok"] and c["lemma2"]["numbers"]["t_norm_hamiltonian"] == float("inf")
    assert not c["lemma5"]["ok"]
    assert not c["lemma4"]["ok"]
    with pytest.raises(RobustDrakeError):
        solve_eq17(k01, k02, 0.3)


@pytest.mark.parametrize("k01,k02", [(25.0, 5.0), (8.0, 4.0), (120.0, 9.0)])
def test_eq17_hamiltonian_and_sdp_agree(k01, k02):
    gamma = 0.8 * gamma_max(k01, k02)
    Ph = solve_eq17(k01, k02, gamma, "hamiltonian")
    Ps = solve_eq17(k01, k02, gamma, "sdp")
    A, B, C = eq17_data(k01, k02)
    scale = np.linalg.norm(C.T @ C)
    assert are_residual(A, B, C, gamma, Ph) < 1e-10 * scale
    assert are_residual(A, B, C, gamma, Ps) < 1e-5 * scale
    assert np.linalg.norm(Ph - Ps) < 1e-6 * np.linalg.norm(Ph)


def test_largest_gamma_is_the_existence_boundary():
    # Lemma 5 / bounded-real lemma: a stabilising P0 exists just below 1/||t|| and not just above.
    for k01, k02 in [(25.0, 5.0), (8.0, 4.0)]:
        g = gamma_max(k01, k02)
        P0 = solve_eq17(k01, k02, g * (1 - 1e-3))
        assert np.min(np.linalg.eigvalsh(P0)) > 1.0
        with pytest.raises(SolverError):
            solve_eq17(k01, k02, g * (1 + 1e-3))
        with pytest.raises(SolverError):
            solve_eq17(k01, k02, g * (1 + 1e-3), "sdp")
        assert lemmas.lemma5(k01, k02, g * 1.01).ok is False


def test_case_study_design_and_pd_gain_independence():
    # (25, 5) with delta = 1 is (kappa01, kappa02) = (25, 5); |t(j w)| peaks at sqrt(5) = 2.236
    assert gamma_max(25.0, 5.0) == pytest.approx(1 / np.sqrt(5.0), rel=1e-8)
    d1 = design_riccati(np.diag([25.0, 25.0]), np.diag([5.0, 5.0]), alpha=0.45)
    d2 = design_riccati(np.diag([100.0, 100.0]), np.diag([10.0, 10.0]), alpha=0.45)
    # omega_n doubled at equal zeta: delta doubles, the kappas and P0 are the same
    assert d2.delta == pytest.approx(2 * d1.delta, rel=1e-6)
    assert np.allclose(d1.P0, d2.P0, rtol=1e-6)
    assert d1.gamma <= d1.gamma_max and d1.gamma >= 0.45
    c = lemmas.check_all(d1.kappa01, d1.kappa02, d1.delta, d1.gamma)
    assert all(c[f"lemma{i}"]["ok"] for i in range(1, 6))
    # z = B^T P e: P in e-ordering is positive definite
    assert np.min(np.linalg.eigvalsh(d1.P)) > 0
    with pytest.raises(RobustDrakeError):
        design_riccati(np.diag([25.0, 25.0]), np.diag([5.0, 5.0]), alpha=0.7)  # alpha > sup gamma_max
    with pytest.raises(RobustDrakeError):
        design_riccati(np.diag([25.0, 30.0]), np.diag([5.0, 5.0]), alpha=0.3)  # unequal joints


def test_lemma3_observability_iff_kappa01_nonzero():
    assert lemmas.lemma3(25.0, 5.0, 0.7).ok
    assert lemmas.lemma3(1e-3, 5.0, 0.7).ok
    c = lemmas.lemma3(0.0, 5.0, 0.7)
    assert not c.ok and c.numbers["pbh_sigma_min_rel"] < 1e-12


def test_hinf_norm_two_ways_mimo_known_value():
    # Diagonal system: ||G||_inf = max over channels; 1/(s^2 + 2 z w s + w^2) has peak 1/(2 z sqrt(1-z^2) w^2)
    z, w = 0.2, 3.0
    A1 = np.array([[0, 1], [-w**2, -2 * z * w]])
    A = scipy.linalg.block_diag(A1, np.array([[-1.0]]))
    B = np.array([[0, 0], [1, 0], [0, 1.0]])
    C = np.array([[1, 0, 0], [0, 0, 0.1]])  # second channel peak 0.1 < first
    exact = 1 / (2 * z * np.sqrt(1 - z**2) * w**2)
    assert hinf_norm_hamiltonian(A, B, C).norm == pytest.approx(exact, rel=1e-8)
    assert hinf_norm_lmi(A, B, C)[0] == pytest.approx(exact, rel=1e-5)
    with pytest.raises(RobustDrakeError):
        hinf_norm_hamiltonian(np.array([[0.1]]), np.ones((1, 1)), np.ones((1, 1)))


def test_lyapunov_case_a():
    d = lyapunov_design(np.diag([25.0, 25.0]), np.diag([5.0, 5.0]))
    ref = scipy.linalg.solve_continuous_lyapunov(d.A.T, -d.Q)
    assert np.allclose(d.P, ref, atol=1e-10)
    assert d.residual < 1e-10 and np.min(np.linalg.eigvalsh(d.P)) > 0
    assert gain_norm(np.diag([25.0, 25.0]), np.diag([5.0, 5.0])) == pytest.approx(np.hypot(25, 5))


def _two_link(m2):
    """Textbook planar 2R arm in a vertical plane (a = 1 m, l = 0.5 m, m1 = 50 kg, I = 10 kg m^2,
    rotor inertia 100 kg m^2 reflected); link-2 mass m2."""
    a1, l1, l2, m1, I1, I2, Ir, g = 1.0, 0.5, 0.5, 50.0, 10.0, 10.0, 100.0, 9.81

    def M(q):
        c2 = np.cos(q[1])
        m11 = I1 + m1 * l1**2 + I2 + m2 * (a1**2 + l2**2 + 2 * a1 * l2 * c2) + Ir
        m12 = I2 + m2 * (l2**2 + a1 * l2 * c2)
        m22 = I2 + m2 * l2**2 + Ir
        return np.array([[m11, m12], [m12, m22]])

    def n(q, v):
        h = -m2 * a1 * l2 * np.sin(q[1])
        cor = np.array([h * (2 * v[0] * v[1] + v[1] ** 2), -h * v[0] ** 2])
        g1 = (m1 * l1 + m2 * a1) * g * np.cos(q[0]) + m2 * l2 * g * np.cos(q[0] + q[1])
        g2 = m2 * l2 * g * np.cos(q[0] + q[1])
        return cor + np.array([g1, g2])

    return M, n


def test_bounds_really_bound_the_uncertainty():
    M, n = _two_link(50.0)
    _, n_hat = _two_link(60.0)  # link-2 mass +20 % in the estimate
    M_hat = np.diag(np.diag(M(np.zeros(2))))
    t = np.linspace(0, 2, 41)
    q_d = np.stack([0.3 + 0.5 * t, 1.0 - 0.2 * t], axis=1)
    qd_d = np.tile([0.5, -0.2], (len(t), 1))
    qdd_d = np.zeros_like(qd_d)
    configs = sample_configurations("trajectory", 2, q_d=q_d, tube=0.1)
    b = compute_bounds(M, n, n_hat, M_hat, configs, qd_d, qdd_d)
    assert 0 < b.alpha < 1 and 0 < b.B_m <= b.B_M
    rng = np.random.default_rng(1)
    for _ in range(300):
        k = rng.integers(len(t))
        qt = rng.uniform(-0.1, 0.1, 2)
        e_v = rng.normal(size=2) * rng.uniform(0, 3)
        e = np.concatenate([qt, e_v])
        q, v = q_d[k] - qt, qd_d[k] - e_v
        lhs = np.linalg.norm(n_hat(q, v) - n(q, v))
        en = np.linalg.norm(e)
        assert lhs <= (b.alpha_0 + b.alpha_1 * en + b.alpha_2 * en**2) * (1 + 1e-3)
        assert np.linalg.norm(np.eye(2) - np.linalg.solve(M(q), M_hat), 2) <= b.alpha * (1 + 1e-9)
    bw = compute_bounds(M, n, n_hat, M_hat, sample_configurations("workspace", 2, grid=37), qd_d, qdd_d,
                        region="workspace")
    assert bw.alpha >= b.alpha and bw.G >= b.G  # the whole workspace is a superset of the tube
    bA1 = beta_case_a(b, np.diag([25.0, 25.0]), np.diag([5.0, 5.0]))
    bA2 = beta_case_a(b, np.diag([100.0, 100.0]), np.diag([10.0, 10.0]))
    bB = beta_case_b(b)
    assert bA2[1] > bA1[1] > bB[1] and bA1[0] == bB[0] and bA1[2] == bB[2]
