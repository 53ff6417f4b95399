"""CI sections 3-5: uncertainty model, confidence-ellipsoid SDP, certificate."""

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError, SolverError
from robust_drake.identification.ellipsoid import Ellipsoid, certify, solve_ellipsoid
from robust_drake.identification.lfr import random_deltas
from robust_drake.identification.uncertainty import CI_BOUNDS, UncertaintyModel, build_uncertainty_model
from robust_drake.regressor import imi_scara_regressor


def _scalar_model(b=2.0):
    """x = b + delta, |delta| <= 1: the solution set is [b - 1, b + 1] exactly."""
    co = np.zeros((1, 1, 1, 2))
    co[0, 0, 0, 1] = 1.0
    return UncertaintyModel(np.ones((1, 1, 1)), np.full((1, 1), b), co, ["tau1"], np.array([1.0]))


def _toy(K=4, seed=0):
    """1 joint, tau = a th1 + qd th2 with uncertain tau and qdd (small: the full SDP is fast)."""
    rng = np.random.default_rng(seed)
    reg = lambda q, qd, qdd: np.stack([qdd, qd], axis=-1)  # (K, 1, 2)
    q = np.zeros((K, 1))
    qd = rng.uniform(-2, 2, (K, 1))
    qdd = rng.uniform(-5, 5, (K, 1))
    th = np.array([2.0, 0.5])
    tau = (reg(q, qd, qdd) @ th) + rng.uniform(-0.1, 0.1, (K, 1))
    return build_uncertainty_model(reg, q, qd, qdd, tau, {"tau": [0.1], "qdd": [0.05]})


@pytest.mark.parametrize("formulation", ["full", "chordal"])
def test_interval_is_recovered_exactly(formulation):
    r = solve_ellipsoid(_scalar_model(), formulation=formulation)
    assert r.theta0[0] == pytest.approx(2.0, abs=1e-5)
    assert r.P[0, 0] == pytest.approx(1.0, rel=1e-5)        # half-width 1 -> P = 1
    assert r.certificate["inside"] == r.certificate["tested"] == 1000
    assert r.certificate["max_radius"] == pytest.approx(1.0, abs=1e-4)  # vertices reach the boundary


def test_linearised_model_matches_regressor_at_perturbed_data():
    """The IMI regressor is linear in qdd, so the linearisation is exact for tau and qdd noise;
    the normal-equation LFR evaluates to [D^T D, D^T tau] of the perturbed data."""
    rng = np.random.default_rng(1)
    K = 3
    q, qd, qdd = rng.normal(size=(3, K, 2))
    tau = rng.normal(size=(K, 2))
    M = build_uncertainty_model(imi_scara_regressor, q, qd, qdd, tau, CI_BOUNDS)
    assert M.scalar_names == ["tau1", "tau2", "qdd1", "qdd2"]
    assert list(M.sample_lfr(0).block_sizes()) == [1, 1, 2, 2]   # ranks r_k^(j) of eq. 18
    for d in random_deltas(M.n_scalars, 3, rng):
        dd = d.reshape(K, 4)
        D_true = imi_scara_regressor(q, qd, qdd + dd[:, 2:] * CI_BOUNDS["qdd"]).reshape(-1, 8)
        tau_true = (tau + dd[:, :2] * CI_BOUNDS["tau"]).reshape(-1)
        D, t = M.perturbed(d)
        np.testing.assert_allclose(D, D_true, atol=1e-8)
        np.testing.assert_allclose(t, tau_true, atol=1e-12)
        N = M.normal_lfr().evaluate(d)
        np.testing.assert_allclose(N, D_true.T @ np.c_[D_true, tau_true], atol=1e-7)


def test_full_and_chordal_are_certified_and_chordal_is_never_smaller():
    M = _toy()
    full = solve_ellipsoid(M, formulation="full")
    ch = solve_ellipsoid(M, formulation="chordal")
    for r in (full, ch):
        assert r.certificate["inside"] == r.certificate["tested"]
        assert np.all(r.eigenvalues > 0)
    # chordal restricts the Finsler multiplier: its optimum can only be larger or equal
    assert ch.trace >= full.trace * (1 - 1e-4)


def test_drake_and_cvxpy_agree():
    M = _toy(K=5, seed=2)
    a = solve_ellipsoid(M, formulation="full", backend="drake", certify_draws=200)
    b = solve_ellipsoid(M, formulation="full", backend="cvxpy", certify_draws=200)
    assert a.trace == pytest.approx(b.trace, rel=1e-4)
    np.testing.assert_allclose(a.theta0, b.theta0, atol=1e-4 * (1 + np.abs(a.theta0).max()))


def test_imi_five_samples_contains_truth_and_solves_fast():
    from robust_drake.experiments.calafiore import run_ellipsoid_experiment

    out = run_ellipsoid_experiment(5, draws=1000)
    assert out["containment"]["inside"] == out["containment"]["tested"] == 1000
    assert out["true_theta_radius"] <= 1.0                   # the noise respected the bounds
    assert out["solve_seconds"] < 5.0                         # ~0.5 s measured
    assert min(out["eigenvalues"]) > 0


def test_certificate_catches_a_too_small_ellipsoid_and_unbounded_sets_fail():
    M = _toy()
    r = solve_ellipsoid(M, formulation="chordal", certify_draws=0)
    small = Ellipsoid(r.theta0, 0.25 * r.P)
    c = certify(M, small, 1000)
    assert c["inside"] < c["tested"] and c["max_radius"] > 1.0
    # one equation, two unknowns: the LS solution set is unbounded, no ellipsoid exists
    with pytest.raises(SolverError):
        solve_ellipsoid(_toy(K=1), formulation="chordal")


def test_ellipsoid_json_roundtrip(tmp_path):
    from robust_drake.regressor import IMI_P, IMI_THETA0

    e = Ellipsoid(IMI_THETA0, IMI_P)
    e.save(tmp_path / "e.json")
    f = Ellipsoid.load(tmp_path / "e.json")
    np.testing.assert_array_equal(f.P, e.P)
    np.testing.assert_allclose(f.E.T @ f.E, IMI_P, atol=1e-12)
    assert e.radius(IMI_THETA0 + f.E @ np.eye(8)[0]) == pytest.approx(1.0)
    (tmp_path / "bad.json").write_text('{"theta0": [1]}')
    with pytest.raises(RobustDrakeError, match="theta0"):
        Ellipsoid.load(tmp_path / "bad.json")


def test_cli_json_contract_and_csv_input(tmp_path, capsys):
    import json

    import pandas as pd

    from robust_drake.cli import main
    from robust_drake.experiments.calafiore import simulate_identification

    assert main(["ellipsoid", "--robot", "imi_scara", "--samples", "5", "--draws", "200", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    for key in ("theta0", "P", "trace", "solver", "setup_seconds", "solve_seconds", "containment",
                "true_theta_radius"):
        assert key in d
    assert set(d["containment"]) >= {"tested", "inside", "max_radius"}
    assert d["containment"]["inside"] == d["containment"]["tested"] == 200
    s = simulate_identification(8, seed=3)
    cols = {f"{k}{i + 1}": s[k][:, i] for k in ("q", "qd", "qdd", "tau") for i in range(2)}
    pd.DataFrame(cols).to_csv(tmp_path / "m.csv", index=False)
    assert main(["ellipsoid", "--data", str(tmp_path / "m.csv"), "--bounds", "tau=4.5744,0.5459;qdd=0.5892,1.6478",
                 "--draws", "100", "--json", "--save", str(tmp_path / "e.json")]) == 0
    d2 = json.loads(capsys.readouterr().out)
    assert d2["n_samples"] == 8 and d2["true_theta_radius"] is None
    assert Ellipsoid.load(tmp_path / "e.json").theta0.size == 8
    assert main(["ellipsoid", "--data", str(tmp_path / "nope.csv")]) == 2
