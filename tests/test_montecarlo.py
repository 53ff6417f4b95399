"""Monte Carlo draws (JS eq. 93 box, CI ellipsoid) and the system-level robustness test."""

from __future__ import annotations

import json

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.models import (D2R2_LOAD_INTERVALS, D2R2_THETA0, D2R2_THETA_LOADED,
                                 D2R2_THETA_UNLOADED)
from robust_drake.montecarlo import (d2r2_link_params, d2r2_theta_from_load, draw_d2r2,
                                     draw_imi, ellipsoid_radius, imi_realisable,
                                     montecarlo_scenarios, percentile_table, run_montecarlo,
                                     sample_ellipsoid, set_imi_theta)


# ----------------------------------------------------------------------------- D2R2 eq. 93


def test_load_box_corners_reproduce_tables_8_and_9():
    # Tables print 3 decimals: agreement to rounding (+ the URDF's l1 = 0.30 m choice).
    np.testing.assert_allclose(d2r2_theta_from_load(0, 0, 0), D2R2_THETA_UNLOADED, atol=6e-4)
    hi = [D2R2_LOAD_INTERVALS[k][1] for k in ("dm2", "dlc2", "dI2")]
    np.testing.assert_allclose(d2r2_theta_from_load(*hi), D2R2_THETA_LOADED, atol=6e-4)


def test_draws_stay_in_the_box_and_follow_eq_14():
    thetas, deltas = draw_d2r2(500, seed=7, corners=True)
    assert thetas.shape == (508, 3)
    lo = np.array([D2R2_LOAD_INTERVALS[k][0] for k in ("dm2", "dlc2", "dI2")])
    hi = np.array([D2R2_LOAD_INTERVALS[k][1] for k in ("dm2", "dlc2", "dI2")])
    assert np.all(deltas >= lo) and np.all(deltas <= hi)
    assert {tuple(r) for r in deltas[:8]} == {(a, b, c) for a in (lo[0], hi[0])
                                              for b in (lo[1], hi[1]) for c in (lo[2], hi[2])}
    p = d2r2_link_params()
    # theta1 changes only through m2 l1^2; theta3 = m2 l1 lc2 (eq. 14)
    np.testing.assert_allclose(thetas[:, 0] - D2R2_THETA_UNLOADED[0],
                               deltas[:, 0] * p["l1"] ** 2, atol=6e-4)
    np.testing.assert_allclose(thetas[:, 2], (p["m2"] + deltas[:, 0]) * p["l1"]
                               * (p["lc2"] + deltas[:, 1]), rtol=1e-12)
    # every draw is a physical two-link arm (positive-definite mass matrix for all q2)
    assert np.all(thetas[:, 2] ** 2 < thetas[:, 0] * thetas[:, 1])
    # uniform draws: sample means near the interval midpoints
    np.testing.assert_allclose(deltas[8:].mean(axis=0), 0.5 * (lo + hi), rtol=0.08)


# ----------------------------------------------------------------------------- CI ellipsoid


def _imi_ellipsoid():
    from robust_drake.regressor import IMI_P, IMI_THETA0

    return np.asarray(IMI_THETA0, float), np.asarray(IMI_P, float)


def test_ellipsoid_samples_inside_and_on_the_boundary():
    theta0, P = _imi_ellipsoid()
    rng = np.random.default_rng(0)
    pts = sample_ellipsoid(theta0, P, 4000, rng, boundary_fraction=0.25)
    r = ellipsoid_radius(pts, theta0, P)
    np.testing.assert_allclose(r[:1000], 1.0, atol=1e-9)
    assert np.all(r[1000:] <= 1.0 + 1e-12)
    # uniform in the ball: r^m is uniform on [0, 1]
    m = theta0.size
    assert abs(np.median(r[1000:] ** m) - 0.5) < 0.04
    # covariance of a uniform ball of radius 1 is I/(m+2): the sample covariance is P/(m+2)
    cov = np.cov((pts[1000:] - theta0).T)
    np.testing.assert_allclose(np.diag(cov), np.diag(P) / (m + 2), rtol=0.15)
    try:  # same convention as the identification engineer's Ellipsoid, if present
        from robust_drake.uncertainty.ellipsoid import Ellipsoid
    except ImportError:
        return
    np.testing.assert_allclose(Ellipsoid(theta0, P).radius(pts[:50]), r[:50], rtol=1e-9)


def test_set_imi_theta_round_trip_and_unrealisable_draws():
    from robust_drake.models import make_plant
    from robust_drake.regressor import imi_theta_from_plant

    theta0, P = _imi_ellipsoid()
    thetas, radii, rejected = draw_imi(theta0, P, 6, seed=3)
    assert thetas.shape == (6, 8) and np.all(radii <= 1 + 1e-9)
    np.testing.assert_allclose(radii[:3], 1.0, atol=1e-9)
    assert rejected > 0  # theta0 itself has Gamma2z = -0.09 < 0: much of E is unphysical
    plant = make_plant("imi_scara")
    for th in thetas:
        ctx = plant.CreateDefaultContext()
        set_imi_theta(plant, ctx, th)
        np.testing.assert_allclose(imi_theta_from_plant(plant, ctx), th[:4], rtol=1e-9, atol=1e-9)
    assert not imi_realisable(theta0)
    with pytest.raises(RobustDrakeError, match="not physically realisable"):
        set_imi_theta(plant, plant.CreateDefaultContext(), theta0)


# ----------------------------------------------------------------------------- system level


def _in_sp_sets(theta):
    from robust_drake.systems.controllers.spong import D2R2_RHO_SP1, D2R2_RHO_SP2

    d = np.asarray(theta) - np.asarray(D2R2_THETA0)
    return np.linalg.norm(d) <= D2R2_RHO_SP1 and np.all(np.abs(d) <= np.asarray(D2R2_RHO_SP2))


def test_robust_controllers_ultimately_bounded_over_the_uncertainty_set():
    """JS section 3.1 (Spong 1992): with the true theta inside the uncertainty set used for
    the design, SP1/SP2 make the tracking error uniformly ultimately bounded. Over draws in
    that set (the load corner pulled just inside, the unloaded arm, the nominal theta0 and a
    random draw) every run stays bounded, the ultimate error (t >= 0.2 s) stays below
    0.02 rad, and it hardly depends on the draw (worst/best <= 1.5). PD, with no model,
    is run alongside: its error changes with the load by more than that, which shows the
    spread check can fail."""
    from robust_drake.systems.controllers.spong import D2R2_RHO_SP1, D2R2_RHO_SP2

    theta0 = np.asarray(D2R2_THETA0)
    d = d2r2_theta_from_load(*[D2R2_LOAD_INTERVALS[k][1] for k in ("dm2", "dlc2", "dI2")]) - theta0
    # The eq. 93 corners sit on the sets' edges (the unloaded arm exactly, up to floating
    # point; the maximum load 0.1065 vs rho = 0.1062 after the URDF's rounding): pull them
    # just inside both the SP1 ball and the SP2 box.
    def inside(theta):
        e = np.asarray(theta) - theta0
        return theta0 + 0.99 * e * min(1.0, D2R2_RHO_SP1 / np.linalg.norm(e),
                                       *(np.asarray(D2R2_RHO_SP2) / np.maximum(np.abs(e), 1e-12)))

    random_draws, _ = draw_d2r2(20, seed=11)
    thetas = [inside(theta0 + d), inside(D2R2_THETA_UNLOADED), theta0,
              next(t for t in random_draws if _in_sp_sets(t))]
    assert all(_in_sp_sets(t) for t in thetas)
    scenarios = montecarlo_scenarios("d2r2", ["sp1", "sp2", "pd"], thetas,
                                     base={"duration": 0.6, "extra": {"metrics_skip": 0.2}})
    df = run_montecarlo(scenarios, workers=2, progress=False)
    df["ultimate"] = df[["maxerr1", "maxerr2"]].max(axis=1)
    table = percentile_table(df, metric="ultimate")
    print("\n" + table[["controller", "runs", "ok", "p50", "worst", "worst_draw"]].to_string())
    spread = {}
    for ctrl, g in df.groupby("controller"):
        assert list(g["status"]) == ["ok"] * len(thetas), g["error"].tolist()
        worst = g.loc[g["ultimate"].idxmax()]
        spread[ctrl] = g["ultimate"].max() / g["ultimate"].min()
        if ctrl in ("sp1", "sp2"):
            assert worst["ultimate"] < 0.02, (
                f"{ctrl}: ultimate error {worst['ultimate']:.4g} rad at draw {worst['draw']} "
                f"theta={worst['true_theta']}")
            assert spread[ctrl] < 1.5, (ctrl, spread[ctrl], int(worst["draw"]))
    assert spread["pd"] > 1.5, spread  # the non-robust baseline does depend on the load


def test_cli_montecarlo_d2r2_and_imi_scara(tmp_path, capsys):
    from robust_drake.cli import main

    out = tmp_path / "mc.parquet"
    plot = tmp_path / "plots" / "montecarlo_maxerr_task.png"
    status = main(["montecarlo", "--robot", "d2r2", "--controllers", "sp1,pd", "--draws", "2",
                   "--duration", "0.2", "--workers", "1", "--out", str(out), "--plot", str(tmp_path / "plots"),
                   "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert status == 0 and doc["draws"] == 2 and plot.stat().st_size > 1000
    rows = {r["controller"]: r for r in doc["controllers"]}
    assert rows["sp1"]["ok"] == 2 and rows["pd"]["ok"] == 2
    assert rows["sp1"]["worst"] < rows["pd"]["worst"]  # model-based beats PD on loaded draws
    assert len(rows["sp1"]["worst_theta"]) == 3
    # IMI SCARA, ellipsoid file in the identification engineer's format (keys theta0, P)
    theta0, P = _imi_ellipsoid()
    ell = tmp_path / "ell.json"
    ell.write_text(json.dumps({"theta0": theta0.tolist(), "P": P.tolist()}))
    status = main(["montecarlo", "--robot", "imi_scara", "--ellipsoid", str(ell),
                   "--controllers", "pd", "--draws", "2", "--duration", "0.2", "--workers", "1",
                   "--out", str(tmp_path / "imi.parquet"), "--plot", str(tmp_path / "iplots"),
                   "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert status == 0 and doc["controllers"][0]["ok"] == 2 and doc["rejected"] > 0
    assert main(["montecarlo", "--robot", "imi_scara"]) == 2  # needs --ellipsoid
