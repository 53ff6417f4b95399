"""From logs to a guaranteed controller: confidence set of an identified model, CI eq. 15 built
from it, Monte Carlo over plants inside the set against the ultimate bound."""

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.experiments.logs_to_control import LogsToControlConfig, run_logs_to_control
from robust_drake.identification.least_squares import solve_ls
from robust_drake.identification.model import IdentifiedModel
from robust_drake.uncertainty.confidence import confidence_ellipsoid, mahalanobis_radius


def _model(theta, cov, data=None, estimator="least_squares"):
    p = len(theta)
    return IdentifiedModel(robot="x", joint_names=["j1", "j2"], base_names=[f"b{i}" for i in range(p)],
                           base_values=np.asarray(theta), base_covariance=cov, coulomb=np.zeros(2),
                           viscous=np.zeros(2), estimator=estimator, data=data or {})


def test_confidence_ellipsoid_covers_the_truth_at_its_level():
    """Independent rows, Gaussian noise: the 90 % set of the LS estimate (solve_ls's covariance)
    holds the true theta in 90 +- 3 % of 600 repeated experiments (binomial sd 1.2 %)."""
    rng = np.random.default_rng(1)
    theta = np.array([0.3, -1.2, 0.05, 2.0])
    hits = 0
    for _ in range(600):
        Y = rng.normal(size=(60, 2, 4))
        tau = Y @ theta + 0.1 * rng.normal(size=(60, 2))
        fit = solve_ls(Y, tau, [f"b{i}" for i in range(4)])
        th0, P = confidence_ellipsoid(_model(fit.theta, fit.cov), alpha=0.1)
        hits += mahalanobis_radius(th0, P, theta) <= 1.0
    assert 0.87 <= hits / 600 <= 0.93, hits / 600


def test_least_squares_covariance_is_inflated_by_n_over_n_eff_but_iv_is_not():
    cov = np.diag([1.0, 4.0])
    data = {"dt": 0.004, "filter": {"cutoff_hz": 10.0}}  # N_eff / N = 2 * 10 * 0.004 = 0.08
    _, P_ls = confidence_ellipsoid(_model([0.0, 0.0], cov, data), alpha=0.05)
    _, P_iv = confidence_ellipsoid(_model([0.0, 0.0], cov, data, "instrumental_variables"), alpha=0.05)
    assert np.allclose(P_ls, P_iv / 0.08)
    assert np.allclose(P_iv, 5.991464547 * cov)  # chi2_{2, 0.95} from tables


def test_confidence_ellipsoid_refuses_bad_inputs():
    with pytest.raises(RobustDrakeError):
        confidence_ellipsoid(_model([0.0], None))
    with pytest.raises(RobustDrakeError):
        confidence_ellipsoid(_model([0.0], np.eye(1)), alpha=1.5)
    with pytest.raises(RobustDrakeError):
        confidence_ellipsoid(_model([0.0, 0.0], np.diag([1.0, 0.0])))


@pytest.fixture(scope="module", params=["dfki_double_pendulum_c1", "siciliano_2link", "puma560_3link"])
def loop(request):
    """5 s experiment (843 rows), torque noise 2 % of the largest gravity torque, 6 draws (3 on the
    boundary of the 99 % set, 3 inside); about 7 s (C.1), 5 s (Siciliano), 18 s (PUMA)."""
    return run_logs_to_control(LogsToControlConfig(robot=request.param, draws=6))


def test_truth_lies_in_the_identified_set(loop):
    assert loop["truth_radius"] <= 1.0, loop["truth_radius"]
    assert 500 < loop["samples"] < 1200 and loop["rho"] > 0


def test_every_draw_stays_within_its_per_joint_bound(loop):
    assert len(loop["draws"]) == 6
    for d in loop["draws"]:
        assert d["radius"] <= 1.0 + 1e-9 and not d["diverged"]
        assert len(d["bound_per_joint"]) == len(d["max_error_per_joint"]) == len(loop["K"])
        for e, b in zip(d["max_error_per_joint"], d["bound_per_joint"]):
            assert 0 < e <= b, d


def test_draws_reach_across_the_set(loop):
    """Half the draws aim at the boundary (radius 1, recomputed from Drake's parameters of the
    drawn plant), the interior ones are spread (uniform in the p-ball: radius u^(1/p)). Where no
    rigid body realises the drawn point (the PUMA: its link-3 inertias are poorly excited, most of
    the set is no rigid body), the nearest physically valid point of the set replaces it, just
    inside (measured 0.988-0.989). The plants differ from the truth by more than 5 % in a link
    inertia (measured 22 % C.1, 9 % Siciliano with 8 draws), not ~0.1 %."""
    draws = loop["draws"]
    aimed = [d for d in draws if d["kind"] == "boundary"]
    assert len(aimed) == 3
    for d in aimed:
        assert (0.9 < d["radius"] <= 0.999 + 1e-6) if d["projected"] else abs(d["radius"] - 1.0) < 1e-6, d
    assert any(not d["projected"] for d in aimed)
    assert min(d["radius"] for d in draws) < 0.99
    izz = [v for k, v in loop["spread"].items() if k.startswith("Izz")]
    assert max(izz) > 0.05, loop["spread"]


def test_bound_is_not_vacuous(loop):
    """The guaranteed bound is far below what PD with the same K, Lambda reaches on the URDF arm
    (measured 0.002x-0.04x), and within a small factor of the error it guarantees: every draw's
    bound / max error below 10 (measured 1.9-5.8 over the three arms)."""
    assert loop["bound"] < 0.1 * loop["pd_max_error"], (loop["bound"], loop["pd_max_error"])
    for d in loop["draws"]:
        assert d["ratio"] < 10.0, d


def test_global_mass_grid_where_at_most_two_joints_change_m(loop):
    """The planar 2-link arms' M depends on the elbow only, the PUMA's on shoulder and elbow (the
    waist turns about the vertical): the bound uses a global grid over those joints."""
    assert loop["region"]["kind"] == "global"
    assert loop["region"]["joints"] == ([1] if len(loop["K"]) == 2 else [1, 2])


def test_arms_the_loop_cannot_handle_are_refused_with_the_reason():
    with pytest.raises(RobustDrakeError, match="gravity torque"):
        run_logs_to_control(LogsToControlConfig(robot="imi_scara"))
    with pytest.raises(RobustDrakeError, match="unknown robot"):
        run_logs_to_control(LogsToControlConfig(robot="no_such_arm"))


def _imi_coverage(bounds, n_samples=20, seeds=40, alpha=0.01):
    from robust_drake.experiments.calafiore import simulate_identification
    from robust_drake.identification.least_squares import solve_wls
    from robust_drake.regressor import imi_scara_regressor

    hits = 0
    for seed in range(seeds):
        d = simulate_identification(n_samples, seed, bounds=bounds)
        Y = imi_scara_regressor(d["q"], d["qd"], d["qdd"])
        fit = solve_wls(Y, d["tau"], [f"t{i}" for i in range(8)], warn=False)
        th0, P = confidence_ellipsoid(_model(fit.theta, fit.cov), alpha)
        hits += mahalanobis_radius(th0, P, d["theta_true"]) <= 1.0
    return hits / seeds


def test_chi2_set_is_sound_for_torque_noise_but_not_for_errors_in_variables():
    """IMI SCARA, 20 D-optimal samples (CI section 5): with CI's torque noise only the 99 % set
    holds the truth in >= 90 % of 40 experiments (measured 100 %); with CI's acceleration noise
    too (noise inside the regressor: LS is biased) it does not (measured 72.5 %), which is why the
    repair switches to IV when its Hausman test flags errors in variables."""
    from robust_drake.uncertainty.regression import CI_BOUNDS

    assert _imi_coverage({"tau": CI_BOUNDS["tau"]}) >= 0.9
    assert _imi_coverage(CI_BOUNDS) < 0.9


def test_chi2_set_is_smaller_than_the_lfr_sdp_set_on_the_same_samples():
    """Torque noise only (both sets sound): measured trace(P_chi2) / trace(P_SDP) = 0.43 at 20
    samples; both hold the truth."""
    from robust_drake.experiments.logs_to_control import compare_with_sdp
    from robust_drake.uncertainty.regression import CI_BOUNDS

    c = compare_with_sdp(20, bounds={"tau": CI_BOUNDS["tau"]})
    assert c["trace_ratio"] < 0.6 and c["volume_ratio"] < 1e-3, c
    assert c["truth_radius_chi2"] <= 1.0 and c["truth_radius_sdp"] <= 1.0, c


def test_cli_prints_the_loop_as_json_and_refuses_bad_options(capsys, tmp_path):
    import json

    from robust_drake.cli import main

    assert main(["logs-to-control", "--draws", "2", "--robot", "puma560_3link", "--json",
                 "--plot", str(tmp_path / "figs")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (tmp_path / "figs" / "logs_to_control.png").stat().st_size > 5000
    assert out["uncertainty"]["kind"] == "ellipsoid" and out["rho"] > 0
    assert len(out["uncertainty"]["theta0"]) == 16  # the PUMA's base parameters
    assert len(out["draws"]) == 2 and out["max_error"] <= out["bound"] < out["pd_max_error"]
    for argv, msg in ((["--alpha", "0"], "--alpha"), (["--draws", "0"], "--draws"),
                      (["--transient", "3"], "--transient"), (["--noise-fraction", "0"], "--noise-fraction"),
                      (["--duration", "3"], "--duration"), (["--robot", "imi_scara"], "gravity torque")):
        assert main(["logs-to-control", *argv]) == 2
        assert msg in capsys.readouterr().err


def test_sampled_layer_is_100x_smaller_without_chattering():
    """PUMA: the sampled-loop layer (ultimate_bound.sampled_layer) is ~100x below the previous
    rule (max ||D E||^2 / min K), with the same torque variation on a drawn plant (measured
    identical to 0.3 %) and a smaller error; 8x smaller still, the sampled loop chatters (waist
    torque variation measured 135x)."""
    from robust_drake.experiments.logs_to_control import track_plant, design_eq15, identified_set
    from robust_drake.uncertainty.plant_draws import draw_plants

    cfg = LogsToControlConfig(robot="puma560_3link")
    _, theta0, P, reg, _, _ = identified_set(cfg, None)
    params, _, _, layer, _ = design_eq15(cfg, reg, theta0, P)
    assert layer["epsilon"] < 0.05 * layer["previous_rule_epsilon"], layer
    d = draw_plants(reg, theta0, P, 1, np.random.default_rng(0))[0][0]
    tv, err = [], []
    for eps in (layer["previous_rule_epsilon"], layer["epsilon"], layer["epsilon"] / 8):
        _, res = track_plant(cfg, "calafiore", dict(params, epsilon=eps), d.setup)
        keep = res.t >= cfg.transient
        tv.append(np.abs(np.diff(np.asarray(res.u)[keep], axis=0)).sum(axis=0))
        err.append(np.abs(res.q - res.q_d)[keep].max())
    assert np.all(tv[1] <= 1.05 * tv[0]) and err[1] < err[0], (tv, err)
    assert tv[2].max() > 10 * tv[1].max(), tv


@pytest.mark.slow
def test_seven_joint_arm_from_a_12_s_log():
    """serial7 (48 base parameters, M changed by five joints: the reference tube is used): a 12 s
    log holds the truth in its 99 % set (IV with the filter-aware sandwich covariance); every drawn
    plant stays within its per-joint bound, the bound lies inside the tube it was computed on, within
    30x of the error (measured 6-19) and below PD's measured error (0.0094 against 0.021 rad). With
    the sounder, larger sandwich sets an 8 s log gives a bound above PD's error (0.029 rad) and a 5 s
    log a diverged draw and bounds of 0.2-0.7 rad (verdict "not shown"). About 20 s."""
    out = run_logs_to_control(LogsToControlConfig(robot="serial7", duration=12.0, draws=2))
    assert out["truth_radius"] <= 1.0 and out["region"]["kind"] == "tube" and out["region"]["consistent"]
    for d in out["draws"]:
        assert not d["diverged"] and d["within"], d
        assert d["ratio"] < 30.0, d
    assert out["guaranteed"], out["verdict"]
    assert out["bound"] < out["pd_max_error"], (out["bound"], out["pd_max_error"])
