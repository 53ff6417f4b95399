"""The Jaritz & Spong comparison on the simulated D2R2: the laws' math, then the paper's
conclusions as system-level assertions (whole closed loops: plant with Coulomb + viscous
friction, quantised encoder, torque saturation, 2500 Hz, averaging velocity filter).

Horizons: the CPT tables run the full 2 s trajectory (tables 2, 4, 5: 12 runs); the estimator
study runs the first 1 s CPT segment (the whole rise 0 -> 90 deg, where the velocity is
largest, so noise and boundedness are exercised); the circle runs 2.5 s of the 7 s with the
first 0.36 s skipped (the initial velocity error has died out by then, and ZC's deficit on the
circle is a steady one).
"""

import json
import math

import numpy as np
import pytest

from robust_drake.experiments import jaritz_spong as js
from robust_drake.models import D2R2_THETA0, D2R2_THETA_LOADED, D2R2_THETA_UNLOADED
from robust_drake.systems.controllers.liu_goldenberg import lg_bounds, lg_torque, theta_C, theta_M
from robust_drake.systems.controllers.spong import d2r2_regressor_single
from robust_drake.systems.controllers.spong_friction import d2r2_friction_regressor, extended_bounds
from robust_drake.systems.controllers.zenieh_corless import BETA0, BETA1, BETA2, zc_bounds, zc_torque

HALF = tuple((h - l) / 2 for h, l in zip(D2R2_THETA_LOADED, D2R2_THETA_UNLOADED))


# ------------------------------------------------------------------------------------- math
def test_zc_bounds_recomputed_from_tables_8_9_match_appendix_12_2():
    b0, b1, b2 = zc_bounds(D2R2_THETA_UNLOADED, D2R2_THETA_LOADED)
    assert b0 == pytest.approx(BETA0, rel=0.03), b0
    assert b1 == pytest.approx(BETA1, rel=0.01), b1
    assert b2 == pytest.approx(BETA2, rel=0.01), b2


def test_zc_robust_term_never_exceeds_rho_and_vanishes_without_motion():
    rng = np.random.default_rng(0)
    K, Lam = (30.0, 10.0), (50.0, 20.0)
    for _ in range(200):
        q_d, qd_d, qdd_d, q, v, ve = (rng.normal(size=2) for _ in range(6))
        tau = np.array(zc_torque(q_d, qd_d, qdd_d, q, v, ve, K, Lam, epsilon=25.0))
        qt = q - q_d
        r = ve + np.array(Lam) * qt
        vref = qd_d - np.array(Lam) * qt
        a = qdd_d - np.array(Lam) * ve
        rho = BETA1 * np.linalg.norm(a) + BETA2 * np.linalg.norm(vref) * np.linalg.norm(v)
        robust = tau + np.array(K) * r
        # eq. 25: rho^2 ||r|| / (rho ||r|| + eps) < rho, and it points against r
        assert np.linalg.norm(robust) <= rho + 1e-12
        assert robust @ r <= 1e-12
    # reference at rest, no velocity, no velocity error: pure -K Lambda q~ (a PD)
    tau = zc_torque([0, 0], [0, 0], [0, 0], [0.01, -0.02], [0, 0], [0, 0], K, Lam, epsilon=25.0)
    # a = -Lambda * v_error = 0, vref = -Lambda q~ but ||q'|| = 0 -> rho = 0
    assert np.allclose(tau, [-30 * 50 * 0.01, -10 * 20 * -0.02])


def _drake_d2r2(theta):
    from robust_drake.models import make_plant, set_d2r2_theta

    plant = make_plant("d2r2")
    ctx = plant.CreateDefaultContext()
    set_d2r2_theta(plant, ctx, np.asarray(theta))
    return plant, ctx


def test_lg_parametrisation_reproduces_drake_inverse_dynamics():
    """JS eqs. 30-31, 40-43: Y_M(a) theta_M(q) + Y_C(q', q') theta_C(q) = M(q) a + C(q, q') q',
    checked against Drake's mass matrix and bias term of the D2R2 URDF at the loaded parameters."""
    theta = D2R2_THETA_LOADED
    plant, ctx = _drake_d2r2(theta)
    rng = np.random.default_rng(1)
    for _ in range(20):
        q, qd, a = rng.normal(size=2), rng.normal(size=2), rng.normal(size=2)
        plant.SetPositions(ctx, q)
        plant.SetVelocities(ctx, qd)
        expected = plant.CalcMassMatrix(ctx) @ a + plant.CalcBiasTerm(ctx)
        tM = theta_M(q[1], theta)
        tC = theta_C(q[1], theta)
        YM = np.array([[a[0], a[1], 0.0], [0.0, a[0], a[1]]])
        YC = np.array([qd[1] * qd[0] + (qd[0] + qd[1]) * qd[1], -qd[0] * qd[0]])
        assert np.allclose(YM @ tM + YC * tC, expected, atol=1e-9), (q, qd, a)


def test_lg_law_is_the_nominal_inverse_dynamics_minus_K_r_on_the_reference():
    """On the reference (q~ = q~' = 0, so r = 0) the saturations give u = 0 and eq. 36 is
    M_0 qdd_d + C_0 qd_d, Drake's inverse dynamics at the nominal parameters."""
    plant, ctx = _drake_d2r2(D2R2_THETA0)
    q_d, qd_d, qdd_d = np.array([0.3, 1.1]), np.array([0.7, -0.4]), np.array([2.0, 3.0])
    tau = lg_torque(q_d, qd_d, qdd_d, q_d, qd_d, [0.0, 0.0], D2R2_THETA0, HALF)
    plant.SetPositions(ctx, q_d)
    plant.SetVelocities(ctx, qd_d)
    assert np.allclose(tau, plant.CalcMassMatrix(ctx) @ qdd_d + plant.CalcBiasTerm(ctx), atol=1e-9)


def test_lg_plus_bounds_match_appendix_12_3_and_bound_every_arm_in_the_interval():
    for q2 in np.linspace(-math.pi, math.pi, 25):
        c, s = abs(math.cos(q2)), abs(math.sin(q2))
        rho_M, rho_C, (d11, d12, d22) = lg_bounds(q2, HALF)
        assert d11 == pytest.approx(0.1281 + 0.1065 * c, abs=6e-4)
        assert d12 == pytest.approx(0.07502 + 0.05327 * c, abs=6e-4)
        assert d22 == pytest.approx(0.07502, abs=6e-4)
        assert rho_C == pytest.approx(0.053 * s, abs=1e-9)  # the appendix prints 0.050327 (see module doc)
    rng = np.random.default_rng(2)
    for _ in range(300):
        th = np.array(D2R2_THETA_UNLOADED) + rng.uniform(size=3) * (np.array(D2R2_THETA_LOADED) - D2R2_THETA_UNLOADED)
        q2 = rng.uniform(-math.pi, math.pi)
        rho_M, rho_C, _ = lg_bounds(q2, HALF)
        dM = np.array(theta_M(q2, th)) - theta_M(q2, D2R2_THETA0)
        assert np.linalg.norm(dM) <= rho_M + 1e-12  # eq. 32
        assert abs(theta_C(q2, th) - theta_C(q2, D2R2_THETA0)) <= rho_C + 1e-12  # eq. 33


def test_friction_regressor_of_eq92_adds_coulomb_torques():
    rng = np.random.default_rng(3)
    theta = np.array([*D2R2_THETA0, 1.2, 2.3])
    for _ in range(20):
        q, qd, v, a = (rng.normal(size=2) for _ in range(4))
        Y5 = d2r2_friction_regressor(q, qd, v, a)
        Y3 = d2r2_regressor_single(q, qd, v, a)
        assert np.allclose(Y5 @ theta, Y3 @ theta[:3] + np.array([1.2, 2.3]) * np.sign(qd))
    rho1, rho2 = extended_bounds()
    assert rho1 == pytest.approx(math.sqrt(0.1062 ** 2 + 0.5 ** 2 + 1.0 ** 2))
    assert rho2 == (0.053, 0.075, 0.053, 0.5, 1.0)


def test_published_tables_are_complete_and_in_metric_order():
    for t in range(2, 8):
        for c in js.CONTROLLERS:
            row = js.published_row(t, c)
            assert set(row) == {"error1", "maxerr1", "error2", "maxerr2", "error_task", "maxerr_task"}
            assert all(v > 0 for v in row.values())
    assert js.published_row(6, "zc")["error1"] == 0.0681  # spot check against the text
    with pytest.raises(Exception, match="tables 2-7"):
        js.run_spec(8, "sp1")


# ------------------------------------------------------------------------- system level: CPT
@pytest.fixture(scope="module")
def cpt():
    """Tables 2 (no compensation), 4 (compensation) and 5 (compensation, maximum load)."""
    out = {}
    for t in (2, 4, 5):
        rows = js.run_table(t, workers=1, progress=False)
        for r in rows:
            assert "error" not in r, r
            assert not r["diverged"], r
        out[t] = {r["controller"]: r for r in rows}
    return out


def _et(rows):
    return {c: round(r["error_task"], 5) for c, r in rows.items()}


def test_sp1_and_sp2_within_a_few_percent(cpt):
    for t, rows in cpt.items():
        a, b = rows["sp1"]["error_task"], rows["sp2"]["error_task"]
        assert abs(a - b) / min(a, b) < 0.10, f"table {t}: SP1 {a:.5f} vs SP2 {b:.5f} m"
        a, b = rows["sp1"]["maxerr_task"], rows["sp2"]["maxerr_task"]
        assert abs(a - b) / min(a, b) < 0.10, f"table {t}: maxerr SP1 {a:.5f} vs SP2 {b:.5f} m"


def test_zc_is_clearly_worst_in_task_space_on_the_cpt(cpt):
    for t, rows in cpt.items():
        zc = rows["zc"]["error_task"]
        best_other = max(rows[c]["error_task"] for c in ("sp1", "sp2", "lgplus"))
        assert zc > best_other, f"table {t}: ZC not worst: {_et(rows)}"
        assert rows["zc"]["maxerr_task"] > max(rows[c]["maxerr_task"] for c in ("sp1", "sp2", "lgplus")), t
    for t in (4, 5):  # with the friction compensated, ZC's missing model terms dominate
        rows = cpt[t]
        ratio = rows["zc"]["error_task"] / max(rows[c]["error_task"] for c in ("sp1", "sp2", "lgplus"))
        assert ratio > 1.5, f"table {t}: ZC only {ratio:.2f}x the others: {_et(rows)}"


def test_friction_compensation_lowers_the_errors(cpt):
    for c in js.CONTROLLERS:
        off, on = cpt[2][c], cpt[4][c]
        for k in ("error_task", "maxerr_task", "error2"):
            assert on[k] < off[k], f"{c}: {k} with compensation {on[k]:.5f} >= without {off[k]:.5f}"
    # the paper: "accuracy is improved by up to 50 % and more"
    gain = min(cpt[2][c]["error_task"] / cpt[4][c]["error_task"] for c in ("sp1", "sp2"))
    assert gain > 2.0, gain


def test_the_loaded_arm_tracks_worse(cpt):
    for c in js.CONTROLLERS:
        un, lo = cpt[4][c]["error_task"], cpt[5][c]["error_task"]
        assert lo > un, f"{c}: loaded {lo:.5f} m <= unloaded {un:.5f} m"


# ------------------------------------------------------------------------------ estimators
def test_every_estimator_keeps_the_loop_bounded_and_euler_is_the_noisiest():
    """Section 6: SP1 + compensation on the first CPT segment with each velocity estimator."""
    observers = ["averaging", "euler", "filtered", "averaging67", "kalman", "nonlinear"]
    specs = [js.run_spec(4, "sp1", duration=1.0, observer=o) for o in observers]
    rows = {o: r for o, r in zip(observers, js.run_specs(specs, workers=1, progress=False))}
    summary = {o: (round(r["error_task"], 5), np.round(r["v_noise"], 4).tolist(), np.round(r["tau_tv_per_s"]).tolist())
               for o, r in rows.items()}
    for o, r in rows.items():
        assert "error" not in r and not r["diverged"], (o, r)
        assert r["maxerr_task"] < 5e-3, f"{o}: maxerr_task {r['maxerr_task']:.4f} m: {summary}"
        assert max(r["tau_peak"]) < 31.2, f"{o}: saturating: {r['tau_peak']}"
    for o in observers:
        if o == "euler":
            continue
        for j in range(2):
            assert rows["euler"]["v_noise"][j] > 1.5 * rows[o]["v_noise"][j], f"joint {j + 1}: {summary}"
        assert sum(rows["euler"]["tau_tv_per_s"]) > sum(rows[o]["tau_tv_per_s"]), summary


# -------------------------------------------------------------------------------- circle
def test_circle_sp1_best_zc_worst():
    """Tables 6-7 conclusion on a shortened circle (2.5 s, first 0.36 s skipped)."""
    specs = [js.run_spec(7, c, duration=2.5) for c in ("sp1", "zc")]
    rows = {r["controller"]: r for r in js.run_specs(specs, workers=1, progress=False)}
    assert not rows["sp1"]["diverged"] and not rows["zc"]["diverged"]
    sp1, zc = rows["sp1"]["error_task"], rows["zc"]["error_task"]
    assert zc > 2 * sp1, f"circle, load: ZC {zc:.5f} vs SP1 {sp1:.5f} m"
    # the paper's headline: the end effector stays within 2 mm of the circle with load
    assert rows["sp1"]["maxerr_task"] < 2e-3, rows["sp1"]["maxerr_task"]


def test_robust_friction_variant_compensates_friction():
    """Section 7.2: SP1 with Coulomb terms in the regressor (eqs. 91-92), no fixed compensation,
    tracks the CPT far better than SP1 without any compensation (table 2's setting)."""
    base = js.run_spec(2, "sp1", duration=1.0)
    rf = dict(base, controller="sp1_robust_friction")
    rows = js.run_specs([base, rf], workers=1, progress=False)
    assert not rows[1]["diverged"], rows[1]
    assert rows[1]["error_task"] < 0.5 * rows[0]["error_task"], (rows[0]["error_task"], rows[1]["error_task"])


# ---------------------------------------------------------------------------------- CLI
def test_compare_json_contract(capsys):
    from robust_drake.cli import main

    status = main(["compare", "--table", "4", "--duration", "0.3", "--workers", "1", "--json",
                   "--controllers", "sp1,zc"])
    assert status == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["controller"] for r in rows] == ["sp1", "zc"]
    for r in rows:
        assert r["load"] == "none" and r["friction_compensation"] is True
        for k in ("error1", "maxerr1", "error2", "maxerr2", "error_task", "maxerr_task"):
            assert isinstance(r[k], float) and r[k] > 0
        assert r["published"]["error_task"] == js.PUBLISHED[4][r["controller"]][4]


def test_compare_rejects_unknown_table(capsys):
    from robust_drake.cli import main

    assert main(["compare", "--table", "9"]) == 2
    assert "tables 2-7" in capsys.readouterr().err


def test_lg_plus_beats_lg_on_the_loaded_arm(cpt):
    """Section 3.3: with the nominal parameters at the unloaded arm (LG) the loaded arm tracked
    poorly; centring them (LG+) fixes it. Table 5 setting (compensation, maximum load)."""
    lg = js.run_specs([js.run_spec(5, "lg")], workers=1, progress=False)[0]
    assert not lg["diverged"], lg
    plus = cpt[5]["lgplus"]
    assert plus["error_task"] < lg["error_task"], (plus["error_task"], lg["error_task"])
    assert plus["error1"] < lg["error1"], (plus["error1"], lg["error1"])


def test_zc_guarantee_holds_and_is_loose_on_the_cpt(cpt):
    """ZC is an s-alpha tracking controller (section 8, Zenieh & Corless): the error converges at rate
    alpha to within the tolerance s allowed by eqs. 24, 26, 27. The CPT starts on the trajectory, so the
    simulated joint errors must stay below s throughout; and the paper blames ZC's conservatism
    (section 9): the guarantee is loose, the measured error a small fraction of s."""
    from robust_drake.systems.controllers.zenieh_corless import zc_guarantee

    g = zc_guarantee(epsilon=25.0)
    alpha, s = g["alpha_max"], g["s"]
    # the returned pair satisfies the paper's inequalities with K = diag(30, 10), Lambda = diag(50, 20):
    assert alpha <= 20.0                                              # (24) lambda_min(Lambda) >= alpha
    assert 10.0 >= alpha * BETA1 * (1 - 1e-12)                        # (26) lambda_min(K) > alpha beta1 (limit)
    assert 25.0 <= (alpha * s) ** 2 * 10.0 * BETA0 / BETA1 * (1 + 1e-12)  # (27) epsilon admissible at s
    assert 25.0 > (alpha * 0.99 * s) ** 2 * 10.0 * BETA0 / BETA1       # ... and s is the smallest such
    worst = max(max(rows["zc"]["maxerr1"], rows["zc"]["maxerr2"]) for rows in cpt.values())
    assert worst < 0.1 * s, (worst, s)


def test_a_failed_run_is_reported_and_the_others_complete():
    """The nonlinear observer refuses 500 Hz (its Euler poles leave the unit circle); the table
    machinery reports that run's error and still returns the good run."""
    good = js.run_spec(4, "sp1", duration=0.1)
    bad = js.run_spec(4, "sp1", duration=0.1, rate=500.0, observer="nonlinear")
    rows = js.run_specs([bad, good], workers=1, progress=False)
    assert "unstable" in rows[0]["error"] and math.isnan(rows[0]["error_task"])
    assert "error" not in rows[1] and rows[1]["error_task"] > 0
    assert "FAILED" in js.format_paper_table(4, rows)


# ------------------------------------------------------------------------------ section 7 (friction)
def test_friction_curve_is_the_torque_the_plant_block_applies():
    """JS fig. 3 analog: the plotted curve is what the simulated plant's friction block applies
    (evaluated through the Drake system), and the Coulomb approximation differs from it by at most
    |F_C - k_hat| + F_v |qd|."""
    from robust_drake.systems.friction import CoulombViscousFriction

    c = js.friction_curve(qd_max=2.0, points=41)
    blk = CoulombViscousFriction(2, c["coulomb"], c["viscous"])
    ctx = blk.CreateDefaultContext()
    for i in range(0, 41, 4):
        blk.get_input_port(0).FixValue(ctx, [0.3, -0.1, c["qd"][i], -c["qd"][i]])
        out = blk.get_output_port(0).Eval(ctx)
        assert -out[0] == pytest.approx(c["plant"][i, 0], abs=1e-12)
        assert out[1] == pytest.approx(c["plant"][i, 1], abs=1e-12)      # odd in qd
    gap = np.abs(c["plant"] - c["coulomb_hat"])
    allowed = np.abs(np.subtract(c["coulomb"], c["k_hat"])) + np.outer(np.abs(c["qd"]), c["viscous"])
    assert np.all(gap <= allowed + 1e-12)
    assert np.all(np.diff(c["plant"], axis=0) >= 0)                       # friction is monotone in qd


def test_friction_group_of_zc_lg_variants_dissipates_any_friction_within_bounds():
    """The friction term added to ZC / LG: r^T (Y_F (k_hat + u_F) - F_C sgn q') <= eps_F rho_F / 4 for
    every true Coulomb level with |k - k_hat| <= rho_k (the boundary-layer bound), q' != 0."""
    from robust_drake.systems.controllers.spong_friction import K_HAT, RHO_K, friction_robust_term

    rng = np.random.default_rng(4)
    rho = math.hypot(*RHO_K)
    Lam = (50.0, 20.0)
    worst = -np.inf
    for _ in range(2000):
        q_d, dq, v, ve = rng.normal(size=(4, 2))
        scale = rng.choice([1e-4, 1e-3, 1e-2, 1.0])
        q, ve = q_d + scale * dq, scale * ve
        k = np.array(K_HAT) + rng.uniform(-1, 1, 2) * np.array(RHO_K)
        r = ve + np.array(Lam) * (q - q_d)
        f = np.array(friction_robust_term(q_d, q, v, ve, Lam))
        worst = max(worst, r @ (f - k * np.sign(v)))
    assert worst <= 1.0 * rho / 4 + 1e-12
    assert worst > 0.5 * rho / 4                 # and is approached inside the layer (not vacuous)


def test_zc_and_lg_plus_with_friction_inside_beat_no_compensation():
    """Table 2 setting (no fixed compensation), 1 s CPT: friction inside ZC / LG+ tracks better than
    the rigid laws with no compensation at all (measured: ZC 0.0358 -> 0.0167 m, LG+ 0.0270 -> 0.0086 m).
    The paper's 'much worse than fixed compensation' is NOT reproduced (BUILD_NOTES) and not asserted."""
    specs = []
    for c in ("zc", "lgplus"):
        base = js.run_spec(2, c, duration=1.0)
        specs += [base, dict(base, controller=f"{c}_robust_friction", controller_params={})]
    rows = js.run_specs(specs, workers=1, progress=False)
    for plain, rf in (rows[0:2], rows[2:4]):
        assert not rf["diverged"], rf
        assert rf["error_task"] < 0.7 * plain["error_task"], (plain["controller"], plain["error_task"], rf["error_task"])


def test_zc_robust_friction_refuses_double_compensation():
    from robust_drake.diagram import ClosedLoopConfig, simulate
    from robust_drake.errors import RobustDrakeError

    with pytest.raises(RobustDrakeError, match="compensated twice"):
        simulate(ClosedLoopConfig(robot="d2r2", controller="zc_robust_friction", trajectory="cpt",
                                  friction_compensation=True, duration=0.01))


def test_viscous_compensation_adds_the_viscous_torque():
    """Section 7.1 with the viscous term: SP1 on the 1 s CPT tracks better with F_v_hat v added
    (measured 0.00626 -> 0.00528 m; the paper found no significant gain, BUILD_NOTES), and the
    command rises by about F_v_hat v on average."""
    rows = js.run_specs([js.run_spec(4, "sp1", duration=1.0),
                         js.run_spec(4, "sp1", duration=1.0, viscous_compensation=True)], workers=1, progress=False)
    assert rows[1]["viscous_compensation"] and not rows[0]["viscous_compensation"]
    assert rows[1]["error_task"] < 0.95 * rows[0]["error_task"], (rows[0]["error_task"], rows[1]["error_task"])
    with pytest.raises(Exception, match="tables 4-7"):
        js.run_spec(2, "sp1", viscous_compensation=True)


def test_eq65_velocity_error_filter_resonates_on_the_flexible_arm_only():
    """Section 6: the eq. 65 velocity-error filter 'was not working sufficiently' and eq. 66 replaced it.
    Reproduced by the flexible D2R2 only (1 s CPT, table 4, SP1; measured error_task 0.0509 vs 0.0071 m,
    joint-1 torque TV 40982 vs 2383 N m/s); on the rigid arm eq. 65 equals eq. 64 (0.00954 vs 0.00953)."""
    specs = [js.run_spec(4, "sp1", observer=o, model="flexible", duration=1.0) for o in ("averaging", "averaging65")]
    avg, e65 = js.run_specs(specs, workers=1, progress=False)
    assert e65["error_task"] > 3 * avg["error_task"], (avg["error_task"], e65["error_task"])
    assert e65["tau_tv_per_s"][0] > 5 * avg["tau_tv_per_s"][0]
