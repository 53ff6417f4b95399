"""Bascetta & Rocco section V on the Siciliano arm: designs, closed loops, CLI contract."""

import json

import numpy as np
import pytest

from robust_drake.analysis import lemmas
from robust_drake.experiments.bascetta import run_case_study, simulate_case
from robust_drake.systems.controllers.bascetta_rocco import (
    ModelDynamics,
    case_study_design,
    inverse_dynamics_law,
)


@pytest.fixture(scope="module")
def designs():
    return case_study_design(K_P=25.0, K_D=5.0), case_study_design(K_P=100.0, K_D=10.0)


@pytest.fixture(scope="module")
def study():
    return run_case_study((25.0, 5.0), keep_results=True)


def test_nominal_and_perturbed_models():
    nom = ModelDynamics("siciliano_2link")
    per = ModelDynamics("siciliano_2link", {"link1": 1.2, "link2": 1.2})
    q = np.zeros(2)
    # textbook M at q = 0: 2 I + m l^2 + m (a^2 + l^2 + 2 a l) + 5 kg motor at the elbow + 100 kg m^2 rotor
    assert nom.M(q)[0, 0] == pytest.approx(250.01, abs=1e-6)
    assert nom.M(q)[1, 1] == pytest.approx(122.5, abs=1e-6)
    # gravity at the stretched pose: (50*0.5 + 5*1 + 50*1.5) g; +20 % on the link masses only
    assert nom(q, np.zeros(2))[0] == pytest.approx(105 * 9.81, rel=1e-9)
    assert per(q, np.zeros(2))[0] == pytest.approx((1.2 * 100 + 5) * 9.81, rel=1e-9)


def test_rho_dominates_the_true_uncertainty_case_b_needs_no_gain_term(designs):
    """BR eq. 9 / 13 (Case A) and the inequality after eq. 19 / 20 (Case B), on the Drake model of the
    case study along the line, inside the 0.1 rad tube the bounds were sampled on:
    Case A: ||eta|| <= rho_A(||e||), eta = Delta (qdd_d + K_P q~ + K_D q~dot + w) - M^-1 n~ (eq. 4), ||w|| = rho_A;
    Case B: ||psi|| <= rho_B(||e||) sigma_min(M^-1 M_hat), psi = Delta qdd_d - M^-1 n~ (eq. 14), at both gain
    sets; and at K = (100, 10) Case B's rho would NOT cover Case A's eta (the K e term is what beta_1 of
    Case A pays for)."""
    from robust_drake.analysis.bascetta_bounds import rho
    from robust_drake.models import get_arm
    from robust_drake.trajectories import make_reference

    d1, d2 = designs
    plant = ModelDynamics("siciliano_2link")
    model = ModelDynamics("siciliano_2link", d1["perturbation"])
    ref = make_reference(get_arm("siciliano_2link"), "line")
    rng = np.random.default_rng(3)
    worst_A, worst_B, B_short = 0.0, 0.0, 0.0
    for _ in range(150):
        q_d, qd_d, qdd_d = (np.asarray(x).reshape(-1) for x in ref(np.array([rng.uniform(0, ref.duration)])))
        e_q = rng.uniform(-0.1, 0.1, 2)
        e_v = rng.normal(size=2) * rng.uniform(0, 1)
        q, v = q_d - e_q, qd_d - e_v
        en = np.linalg.norm(np.concatenate([e_q, e_v]))
        Minv = np.linalg.inv(plant.M(q))
        Delta = np.eye(2) - Minv @ d1["M_hat"]
        nt = model.n_term(q, v) - plant.n_term(q, v)
        u = rng.normal(size=2)
        u /= np.linalg.norm(u)
        psi = Delta @ qdd_d - Minv @ nt
        sig = np.linalg.svd(Minv @ d1["M_hat"], compute_uv=False)[-1]
        for d in designs:
            Ke = d["K_P"] * e_q + d["K_D"] * e_v
            rA, rB = rho(d["beta_A"], en), rho(d["beta_B"], en)
            worst_A = max(worst_A, np.linalg.norm(Delta @ (qdd_d + Ke + rA * u) - Minv @ nt) / rA)
            worst_B = max(worst_B, np.linalg.norm(psi) / (rB * sig))
        rB2 = rho(d2["beta_B"], en)
        B_short = max(B_short, np.linalg.norm(Delta @ (qdd_d + d2["K_P"] * e_q + d2["K_D"] * e_v + rB2 * u)
                                              - Minv @ nt) / rB2)
    assert worst_A <= 1.0 and worst_B <= 1.0, (worst_A, worst_B)
    assert B_short > 1.0, B_short
    b = d1["bounds"]
    assert 0 < b.alpha < 1 and b.B_m <= b.B_M
    # Riccati design admissible: alpha <= gamma < gamma_max, and every lemma certified at both gain sets
    for d in designs:
        r = d["riccati"]
        assert b.alpha <= r.gamma < r.gamma_max
        c = lemmas.check_all(r.kappa01, r.kappa02, r.delta, r.gamma)
        assert all(c[f"lemma{i}"]["ok"] for i in range(1, 6)), c
    # equal zeta: the kappas, hence P0, are the same; delta doubles with omega_n
    assert np.allclose(d1["riccati"].P0, d2["riccati"].P0, rtol=1e-6)


def test_law_without_error_is_feedforward():
    M_hat = np.diag([250.0, 122.5])
    BtP = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    q = np.array([0.3, 0.4])
    u, w, rho = inverse_dynamics_law(q, np.zeros(2), np.array([1.0, 2.0]), q, np.zeros(2), np.full(2, 25.0),
                                     np.full(2, 5.0), M_hat, np.array([10.0, 20.0]), BtP, [2.0, 1.0, 1.0], 0.01)
    assert np.allclose(w, 0) and rho == pytest.approx(2.0)
    assert np.allclose(u, M_hat @ [1.0, 2.0] + [10.0, 20.0])
    # inside the boundary layer w is linear in z, outside it has norm rho
    e_v = np.array([1.0, 0.0])
    _, w_out, rho_out = inverse_dynamics_law(q, e_v, np.zeros(2), q, np.zeros(2), np.full(2, 25.0), np.full(2, 5.0),
                                             M_hat, np.zeros(2), BtP, [2.0, 0.0, 0.0], 0.01)
    assert np.linalg.norm(w_out) == pytest.approx(2.0)


def test_both_cases_track_the_line_and_b_spends_less(study):
    A, B = study["A"], study["B"]
    for s in (A, B):
        assert not s["diverged"]
        assert max(s["error_max"]) < 0.01  # rad, with the 20 % mass error in n_hat
        assert max(s["velocity_error_max"]) < 0.05
    # the sampled bounds hold while the error stays in the 0.1 rad tube they were computed on
    assert max(A["error_max"] + B["error_max"]) < 0.1
    # rho(||e||) >= beta_0 and Case B's rho is below Case A's
    assert A["rho_peak"] >= A["beta"][0] and B["rho_rms"] < A["rho_rms"]
    # energy (2-norm) of w lower in Case B (paper: 11 %)
    assert B["w_energy_total"] < A["w_energy_total"]
    assert study["w_energy_reduction_B_vs_A"] > 0
    r = study["riccati"]
    assert r["residual"] < 1e-8 and min(r["P0_eigs"]) > 1.0


def test_robust_term_is_what_rejects_the_perturbation(study):
    # same loop with w switched off (beta = 0): plain inverse dynamics with the wrong n_hat
    res0, _ = simulate_case_no_w()
    err0 = np.max(np.abs(res0.q - res0.q_d))
    errB = max(study["B"]["error_max"])
    assert err0 > 5 * errB, (err0, errB)


def simulate_case_no_w():
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

    cfg = ClosedLoopConfig(robot="siciliano_2link", controller="bascetta_b",
                           controller_params={"K_P": 25.0, "K_D": 5.0, "beta": [0.0, 0.0, 0.0]},
                           trajectory="line", observer="exact", plant_friction=None,
                           encoder_resolution=None, torque_limit=None)
    cl = build_closed_loop(cfg)
    return cl.simulate(), cl.controller


def test_cli_json_contract(capsys):
    from robust_drake.cli import main

    status = main(["bascetta", "--gains", "25,5", "--duration", "0.3", "--json"])
    assert status == 0
    d = json.loads(capsys.readouterr().out)
    for case in ("A", "B"):
        assert set(["beta", "w_energy", "rho_peak", "rho_rms", "error_max"]) <= set(d[case])
        assert len(d[case]["beta"]) == 3 and len(d[case]["w_energy"]) == 2 and len(d[case]["error_max"]) == 2
    assert set(["gamma", "gamma_max", "P0", "residual"]) <= set(d["riccati"])
    assert np.array(d["riccati"]["P0"]).shape == (2, 2)
    assert main(["bascetta", "--gains", "25"]) == 2


@pytest.mark.parametrize("argv,message", [
    (["bascetta", "--gains", "nan,5"], "K_P = nan"),
    (["bascetta", "--gains", "inf,5"], "K_P = inf"),
    (["bascetta", "--gains", "-25,5"], "K_P = -25"),   # reaches the gain check, not argparse's "expected one argument"
    (["bascetta", "--gains=-25,5"], "K_P = -25"),
    (["bascetta", "--gains", "25,-5"], "K_D = -5"),
])
def test_cli_gains_one_line_errors(argv, message, capsys):
    from robust_drake.cli import main

    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and message in err and "Hurwitz" in err, err


def test_negative_option_values_are_glued_only_for_options_that_take_a_value():
    from robust_drake.cli import build_parser, glue_negative_values

    p = build_parser()
    assert glue_negative_values(p, ["bascetta", "--gains", "-25,5", "--json"]) == ["bascetta", "--gains=-25,5", "--json"]
    assert glue_negative_values(p, ["bascetta", "--json", "-h"]) == ["bascetta", "--json", "-h"]
    assert p.parse_args(glue_negative_values(p, ["bascetta", "--gains", "-25,5"])).gains == "-25,5"


# ------------------------------------------------------------------ section II-C constant rho, sensitivity
def test_constant_rho_dominates_the_error_dependent_rho_and_spends_more(study):
    """Section II-C: the constant gain of [3] is rho_A evaluated at the assumed ||e|| <= E_M, so while
    the error stays below E_M it is >= Case A's rho(||e||) at every instant and w costs more energy
    (measured at E_M = 0.2: +1.4 % energy at (25, 5), +5.7 % at (100, 10): inside the boundary layer w
    is a feedback that cancels eta whatever rho is, so a larger rho costs little energy)."""
    from robust_drake.experiments.bascetta import constant_rho, run_constant_rho

    d = case_study_design(K_P=25.0, K_D=5.0)
    rc = constant_rho(d["bounds"], 25.0, 5.0, 0.2)
    b = d["beta_A"]
    assert rc == pytest.approx(b[0] + b[1] * 0.2 + b[2] * 0.04, rel=1e-9)   # eq. 13 is eq. 10 at ||e|| = E_M
    c = run_constant_rho((25.0, 5.0), E_M=0.2)
    assert c["assumption_held"] and not c["diverged"]
    assert c["rho_peak"] == pytest.approx(rc) and c["rho_rms"] == pytest.approx(rc, rel=1e-3)  # rho = 0 before tick 1
    assert rc > study["A"]["rho_peak"]
    assert c["w_energy_total"] > 1.005 * study["A"]["w_energy_total"]


def test_w_energy_reduction_grows_with_the_gains_and_without_beta0():
    """The Case B saving comes only from beta_1's alpha ||K|| term (eqs. 13 vs 20): it grows with the PD
    gains and when the shared beta_0 shrinks. Measured: 2.0 % at (25, 5), 11.7 % at (100, 10); with
    beta_0 = 0 at (25, 5) the saving is far larger."""
    from robust_drake.experiments.bascetta import sensitivity_study

    rows = sensitivity_study({"gains": [(25.0, 5.0), (100.0, 10.0)], "beta0_scale": [0.0]}, duration=1.2,
                             workers=1)
    red = {(r["axis"], str(r["value"])): r["reduction"] for r in rows}
    low, high, nob0 = red[("gains", "(25.0, 5.0)")], red[("gains", "(100.0, 10.0)")], red[("beta0_scale", "0.0")]
    assert not any(r["diverged"] for r in rows)
    assert 0 < low < high and high > 2 * low, (low, high)
    assert nob0 > 2 * low, (low, nob0)


def test_blown_up_state_is_reported_as_diverged_not_an_abort():
    """Drake aborts the process on SetPositions with a non-finite q; the BR controller's model gives
    NaN there instead, so Case A blowing up on the Panda (1 kHz, step) ends as a diverged run with
    NaN criteria for every joint."""
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop
    from robust_drake.systems.controllers.bascetta_rocco import ModelDynamics

    m = ModelDynamics("siciliano_2link")
    assert np.isnan(m.M(np.array([np.nan, 0.0]))).all()
    assert np.isnan(m.n_term(np.zeros(2), np.array([np.inf, 0.0]))).all()
    # torque_limit=None: the Panda's description saturates at 87/12 N m, which keeps Case A bounded
    res = build_closed_loop(ClosedLoopConfig(robot="panda", controller="bascetta_a", trajectory="step",
                                             duration=0.3, torque_limit=None)).simulate()
    assert res.diverged
    assert all(np.isnan(res.metrics[f"error{j}"]) for j in range(1, 8))
