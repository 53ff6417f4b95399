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
    rho,
    sample_configurations,
)
from robust_drake.analysis.lyapunov import lyapunov_design
from robust_drake.analysis.norms import hinf_norm_hamiltonian, hinf_norm_lmi
from robust_drake.analysis.tolerance import certificate_tol, eig_condition, on_imaginary_axis
from robust_drake.analysis.riccati import (
    are_certificate,
    are_residual,
    bounded_real_are_hamiltonian,
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
    assert n1["max_real_eig"] < 0 and n1["scaling_error"] <= n1["scaling_tol"] < 1e-9
    # Lemma 2: Hamiltonian bisection, KYP LMI, MIMO T_delta and a dense sweep of the closed form agree
    n2 = c["lemma2"]["numbers"]
    w = np.logspace(-3, 3, 20001)
    k = np.argmax(np.abs(t_closed_form(k01, k02, w)))
    w_fine = np.linspace(w[max(k - 1, 0)], w[min(k + 1, len(w) - 1)], 20001)  # resolve sharp resonances
    sweep = max(np.max(np.abs(t_closed_form(k01, k02, w_fine))), np.max(np.abs(t_closed_form(k01, k02, w))))
    assert n2["t_norm_hamiltonian"] == pytest.approx(sweep, rel=1e-7)
    assert n2["t_norm_hamiltonian"] >= sweep * (1 - 1e-9)  # the sweep is a lower bound
    assert n2["t_norm_lmi"] == pytest.approx(n2["t_norm_hamiltonian"], rel=1e-5)
    assert abs(n2["T_delta_norm"] - n2["t_norm_hamiltonian"]) <= n2["T_vs_t_tol"] * n2["t_norm_hamiltonian"]
    assert n2["T_vs_t_tol"] < 1e-8
    # Lemma 5: eigenvalues of P0 above 1, stabilising
    n5 = c["lemma5"]["numbers"]
    assert min(n5["eig_P0"]) > 1.0 and n5["closed_loop_abscissa"] < 0
    # Lemma 4, checked independently of lemmas.py: scipy's generalized-Schur ARE solver (R = -1/gamma^2)
    # on the 4x4 eq. 18 gives bdiag(Pi, Pi) to within the certificate's conditioning-based tolerance,
    # and the residual of eq. 18 written out here is rounding-small relative to its terms.
    n4 = c["lemma4"]["numbers"]
    calA, calB, calC = lemmas.big_system(k01, k02, delta, 2)
    Ad = calA + delta * np.eye(4)
    P_ref = scipy.linalg.solve_continuous_are(Ad, calB, calC.T @ calC, -np.eye(2) / gamma**2)
    Pi = np.array(n4["Pi"])
    Pblock = scipy.linalg.block_diag(Pi, Pi)
    assert np.linalg.norm(Pblock - P_ref) / np.linalg.norm(P_ref) <= n4["tol"]
    R18 = Ad.T @ Pblock + Pblock @ Ad + gamma**2 * Pblock @ calB @ calB.T @ Pblock + calC.T @ calC
    terms = 2 * np.linalg.norm(Ad.T @ Pblock) + gamma**2 * np.linalg.norm(Pblock @ calB) ** 2 + np.linalg.norm(calC) ** 2
    assert np.linalg.norm(R18) <= n4["tol"] * terms
    assert n4["rel_diff"] <= n4["tol"] < 1e-4  # the tolerance stays meaningful on this grid


@pytest.mark.parametrize("k01,k02", BAD)
def test_lemmas_fail_where_16_fails(k01, k02):
    gamma = 0.3
    c = lemmas.check_all(k01, k02, 0.7, gamma)
    # Lemma 1: some eigenvalue of A0 + I in the closed right half plane, computed here by hand:
    # det(sI - (A0 + I)) = s^2 + (k02 - 2) s + (k01 - k02 + 1)
    poles = np.roots([1.0, k02 - 2.0, k01 - k02 + 1.0])
    assert np.max(poles.real) >= -1e-12
    assert not c["lemma1"]["ok"] and c["lemma1"]["numbers"]["max_real_eig_A0_plus_I"] == pytest.approx(
        np.max(poles.real), abs=1e-9)
    # Lemma 2: t(s) has that pole, so |t(j w)| grows without bound near it (or t is unstable):
    # ||t||_inf is not finite and the code must not report a number
    assert c["lemma2"]["numbers"]["t_norm_hamiltonian"] == float("inf")
    # Lemma 5's conclusion fails independently of lemmas.py: scipy's ARE solver either finds no
    # stabilising solution of eq. 17 or finds one that is not positive semidefinite.
    A, B, C = eq17_data(k01, k02)
    try:
        P0 = scipy.linalg.solve_continuous_are(A, B, C.T @ C, -np.eye(1) / gamma**2)
    except (np.linalg.LinAlgError, ValueError):
        P0 = None
    if P0 is not None:
        assert np.min(np.linalg.eigvalsh(P0)) < -1.0  # stabilising but indefinite: no Lyapunov function
    assert not c["lemma5"]["ok"] and not c["lemma4"]["ok"]
    with pytest.raises(RobustDrakeError):
        solve_eq17(k01, k02, gamma)


@pytest.mark.parametrize("k01,k02", [(120.0, 2.5), (25.0, 5.0), (8.0, 4.0)])
def test_lemma4_tolerance_rejects_wrong_answers(k01, k02):
    """The conditioning-based tolerance accepts the correct P at kappa = (120, 2.5) (the case a fixed
    1e-8 rejected) but still rejects a P perturbed by 1e-5 relative, and a Pi from a gamma 1e-4 off."""
    delta = 0.7
    gamma = 0.9 * gamma_max(k01, k02)
    good = lemmas.lemma4(k01, k02, delta, gamma)
    assert good.ok, good.numbers
    calA, calB, calC = lemmas.big_system(k01, k02, delta, 2)
    Ad = calA + delta * np.eye(4)
    Pfull, cond_full = bounded_real_are_hamiltonian(Ad, calB, calC, gamma, with_cond=True)
    Pi = np.array(good.numbers["Pi"])
    cond_block = good.numbers["cond_block"]
    rng = np.random.default_rng(0)
    E = rng.normal(size=(2, 2))
    E = (E + E.T) / np.linalg.norm(E + E.T)
    Pi_bad = Pi + 1e-5 * np.linalg.norm(Pi) * E
    bad = lemmas.lemma4_compare(Ad, calB, calC, gamma, Pfull, cond_full, scipy.linalg.block_diag(Pi_bad, Pi_bad),
                                cond_block, True)
    assert not bad.ok and bad.numbers["rel_diff"] > 3 * bad.numbers["tol"], bad.numbers
    # Pi of eq. 17 at a slightly different gamma: a genuine solution of the wrong equation
    A, B, C = eq17_data(k01, k02)
    P0w = bounded_real_are_hamiltonian(A, B, C, gamma * (1 - 1e-4))
    Bb = np.diag([delta, 1.0])
    Pi_w = delta * Bb @ P0w @ Bb
    wrong = lemmas.lemma4_compare(Ad, calB, calC, gamma, Pfull, cond_full, scipy.linalg.block_diag(Pi_w, Pi_w),
                                  cond_block, True)
    assert not wrong.ok, wrong.numbers
    # the residual certificate alone also rejects the perturbed P0 of eq. 17
    P0, cond0 = bounded_real_are_hamiltonian(A, B, C, gamma, with_cond=True)
    assert are_certificate(A, B, C, gamma, P0, cond0)["ok"]
    assert not are_certificate(A, B, C, gamma, P0 * (1 + 1e-4), cond0)["ok"]


def test_imaginary_axis_test_follows_conditioning():
    # A Hamiltonian with eigenvalues exactly +-j and one scaled by 1e6: a fixed absolute 1e-9 would
    # misjudge one of them; the kappa-based test calls both on the axis and a 1e-6 shift off it.
    for s in (1.0, 1e6):
        H = s * np.array([[0.0, 1.0], [-1.0, 0.0]])
        assert on_imaginary_axis(H)[0].all()
        assert not on_imaginary_axis(H + 1e-6 * s * np.eye(2))[0].any()
    # nearly a Jordan block (kappa ~ 5e6): +-1e-7 j is on the axis, +-1e-7 (real) is not
    for sign, on in ((-1.0, True), (1.0, False)):
        J = np.array([[0.0, 1.0], [sign * 1e-14, 0.0]])
        lam, kappa = eig_condition(J)
        assert np.all(kappa > 1e6) and np.all(on_imaginary_axis(J)[0] == on)
    assert certificate_tol(1.0) == pytest.approx(10 * np.finfo(float).eps)
    assert certificate_tol(float("inf")) == float("inf")


@pytest.mark.parametrize("k01,k02", [(25.0, 5.0), (8.0, 4.0), (120.0, 9.0)])
def test_eq17_hamiltonian_and_sdp_agree(k01, k02):
    gamma = 0.8 * gamma_max(k01, k02)
    Ph = solve_eq17(k01, k02, gamma, "hamiltonian")
    Ps = solve_eq17(k01, k02, gamma, "sdp")
    A, B, C = eq17_data(k01, k02)
    scale = np.linalg.norm(C.T @ C)
    Ph2, cond = bounded_real_are_hamiltonian(A, B, C, gamma, with_cond=True)
    assert np.array_equal(Ph, Ph2) and are_certificate(A, B, C, gamma, Ph, cond)["ok"]
    # independent route: scipy's generalized-Schur solver with R = -1/gamma^2 (the plus sign of eq. 17)
    P_ref = scipy.linalg.solve_continuous_are(A, B, C.T @ C, -np.eye(1) / gamma**2)
    assert np.linalg.norm(Ph - P_ref) <= certificate_tol(cond) * np.linalg.norm(P_ref)
    assert are_residual(A, B, C, gamma, Ps) < 1e-5 * scale  # the SDP is accurate to its solver tolerance
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
    # rho(||e||) must dominate the uncertainty it is designed for (BR eq. 9 for Case A, the
    # inequality after eq. 19 for Case B), evaluated on the true dynamics, not on the formulas:
    # Case A: ||eta|| <= rho_A with eta = Delta (qdd_d + K e + w) - M^-1 n~ (eq. 4), ||w|| = rho_A;
    # Case B: ||psi|| <= rho_B sigma_min(M^-1 M_hat) with psi = Delta qdd_d - M^-1 n~ (eq. 14).
    qdd_d = np.array([0.8, -0.5])  # |qdd_d| inside the sampled Q_M
    b = compute_bounds(M, n, n_hat, M_hat, configs, qd_d, np.tile(qdd_d, (len(t), 1)))
    worst_A, worst_B, gain_needed = 0.0, 0.0, 0.0
    for K_P, K_D in ((25.0, 5.0), (400.0, 40.0)):
        bA = beta_case_a(b, np.diag([K_P, K_P]), np.diag([K_D, K_D]))
        bB = beta_case_b(b)
        for _ in range(200):
            k = rng.integers(len(t))
            qt = rng.uniform(-0.1, 0.1, 2)
            e_v = rng.normal(size=2) * rng.uniform(0, 3)
            q, v = q_d[k] - qt, qd_d[k] - e_v
            en = np.linalg.norm(np.concatenate([qt, e_v]))
            Minv = np.linalg.inv(M(q))
            Delta = np.eye(2) - Minv @ M_hat
            nt = n_hat(q, v) - n(q, v)
            Ke = K_P * qt + K_D * e_v
            u = rng.normal(size=2)
            rA = rho(bA, en)
            eta = Delta @ (qdd_d + Ke + rA * u / np.linalg.norm(u)) - Minv @ nt
            worst_A = max(worst_A, np.linalg.norm(eta) / rA)
            psi = Delta @ qdd_d - Minv @ nt
            sig = np.linalg.svd(Minv @ M_hat, compute_uv=False)[-1]
            worst_B = max(worst_B, np.linalg.norm(psi) / (rho(bB, en) * sig))
            # with the high gains, Case B's rho would not cover Case A's eta: the K e term is real
            rB = rho(bB, en)
            etaB = Delta @ (qdd_d + Ke + rB * u / np.linalg.norm(u)) - Minv @ nt
            gain_needed = max(gain_needed, np.linalg.norm(etaB) / rB)
    assert worst_A <= 1.0 and worst_B <= 1.0, (worst_A, worst_B)
    assert gain_needed > 1.0
