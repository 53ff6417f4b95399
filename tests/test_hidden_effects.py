"""Hidden effects: data from a simulated arm with an effect the fitter is not told about.

For every kind in the effect library, ``hidden_effect_case`` simulates the DFKI C.1 arm (Drake
plant + baseline friction + the effect's block / plant change, PD-tracked Fourier excitation,
14-bit encoder, 5 mN m torque noise; fixed seeds; fit and validation runs use different motions)
and ``repair`` (Python API, no subprocess) must:
  - name the effect (kind and joint) as its first addition (torque_scale: a free fit sees only
    the relative gain; the joint is chosen against the URDF's parameters, see ``nominal.py``),
  - recover the effect's parameter within the case's stated tolerance (``HIDDEN_CASES``: 30 %,
    40 % for the delay, whose column is a first-order expansion),
  - cut the validation RMS torque error of the affected joint (both joints for a global effect)
    at least in half.
Effects outside the library (a torque periodic in time) must be flagged as unexplained structure
and no effect may be claimed with high confidence. ``payload`` is special: a tool mass is exactly
absorbed by the rigid-body base parameters (see ``effects.Payload``), so it is named from the
shift of those parameters against the URDF, and its error cut is URDF-only vs URDF + payload.

Data are short (12 s at 250 Hz per run) so the whole file stays within its time budget.
"""

import json
import math

import numpy as np
import pytest

from robust_drake.effects import DIAGNOSTIC_KINDS, EFFECTS, make_effect
from robust_drake.synthetic.simulated import HIDDEN_CASES, hidden_effect_case

repair = pytest.importorskip("robust_drake.model_repair.pipeline")

# Cost note: ~45-60 s on one core with single-threaded BLAS (``make test`` exports
# OPENBLAS_NUM_THREADS=1). Run directly, export it too: multi-threaded OpenBLAS on a busy 2-core
# machine made each selection 10-30x slower (measured).


def _run(kind, tmp_path_factory, seed=0):
    out = tmp_path_factory.mktemp(f"hidden_{kind}")
    fit, val, truth = hidden_effect_case(kind, seed=seed, out_dir=str(out))
    opts = repair.RepairOptions(robot=truth["robot"], consistent=False, replay=False, plots=False)
    rep = repair.run_repair([fit], opts, validate_paths=[val])
    truth["fit_csv"] = fit
    return rep, truth


def _rms(xs, joints):
    return math.sqrt(sum(xs[j] ** 2 for j in joints))


LIBRARY_CASES = [k for k in EFFECTS if k != "payload" and k not in DIAGNOSTIC_KINDS]


def test_every_library_kind_has_a_hidden_case():
    # diagnostic-driven kinds have their cases in simulated_cases (tests/test_outside_library.py)
    assert set(EFFECTS) - set(DIAGNOSTIC_KINDS) <= set(HIDDEN_CASES)


@pytest.mark.parametrize("kind", LIBRARY_CASES)
def test_repair_names_and_recovers_hidden_effect(kind, tmp_path_factory):
    rep, truth = _run(kind, tmp_path_factory)
    assert rep["effects"], f"{kind}: repair added nothing; steps {rep['selection']['steps']}"
    first = rep["effects"][0]
    assert first["kind"] == kind, f"named {first['label']} instead of {kind}"
    est = first["parameters"][truth["key"]]
    true = truth["parameters"][truth["key"]]
    # torque_scale: a free fit sees only the ratio of joint gains; the joint is picked against
    # the URDF's parameters (nominal.resolve_torque_scale), so it must be the true one too
    assert first["joint"] == truth["joint"], (kind, first["label"], first.get("joint_resolution"))
    assert abs(est - true) <= truth["rtol"] * abs(true), (kind, est, true)
    n = len(rep["baseline"]["rms_validate"])
    # the affected joint; all joints for global effects and for torque_scale (the baseline's free
    # fit spreads a single joint's gain error over both joints' residuals)
    joints = range(n) if truth["joint"] is None or kind == "torque_scale" else [truth["joint"]]
    before = _rms(rep["baseline"]["rms_validate"], joints)
    after = _rms(rep["final"]["rms_validate"], joints)
    assert after <= 0.5 * before, (kind, before, after)
    # nothing else claimed with high confidence, and once the effect is in, the rigid-body
    # parameters sit where the URDF has them: no effect named from a parameter shift
    assert all(e["confidence"] != "high" for e in rep["effects"][1:]), rep["effects"]
    assert not rep["nominal"]["significant"], (kind, rep["nominal"]["chi2"], rep["nominal"]["chi2_limit"])
    assert all(e["source"] == "residual" for e in rep["effects"]), rep["effects"]


def test_effect_outside_library_is_flagged(tmp_path_factory):
    """A time-periodic torque (0.7 Hz, 0.08 N m on joint 1): no library effect depends on time.
    The baseline residual's periodic diagnostic fires on joint 1 at 0.7 Hz, which offers the
    ``periodic_disturbance`` kind to the selection there (and only there): it is named, as a
    disturbance, with its frequency and amplitude, and no library kind is claimed for it."""
    rep, truth = _run("periodic_disturbance", tmp_path_factory)
    j = truth["joint"]
    diag = [d for d in rep["residual"]["baseline"]["diagnostics"] if d["test"] == "periodic" and d["joint"] == j]
    assert diag and diag[0]["frequency_hz"] == pytest.approx(truth["parameters"]["frequency"], rel=0.02)
    assert [(e["kind"], e["joint"]) for e in rep["effects"]] == [("periodic_disturbance", j)], rep["effects"]
    (e,) = rep["effects"]
    assert e["is_disturbance"] is True
    assert e["parameters"]["frequency"] == pytest.approx(truth["parameters"]["frequency"], rel=0.01)
    assert e["parameters"]["amplitude"] == pytest.approx(truth["parameters"]["amplitude"], rel=0.15)
    # the disturbance keeps its phase to the logs' clocks here, so it predicts the validation run
    assert rep["final"]["rms_validate"][j] < 0.5 * rep["baseline"]["rms_validate"][j]


def test_payload_is_named_from_the_parameter_shift(tmp_path_factory):
    """A tool mass lies in the rigid-body span (absorbed by a free fit), so repair names it from
    the shift of the base parameters against the URDF (``nominal.py``): kind, mass within the
    case's tolerance, and the URDF model + payload halves the URDF-only model's validation error."""
    from robust_drake.identification.data import load
    from robust_drake.identification.least_squares import load_regressor

    rep, truth = _run("payload", tmp_path_factory)
    # the free rigid-body fit already explains the data: nothing found in the residual
    assert [e for e in rep["effects"] if e["source"] == "residual"] == []
    assert max(rep["baseline"]["rms_validate"]) < 0.01
    nom = rep["nominal"]
    assert nom["significant"] and not nom["unexplained_shift"]
    (named,) = [e for e in rep["effects"] if e["source"] == "parameter_shift"]
    json.dumps(rep, allow_nan=False)  # strict JSON: the named effect has no standard error (null)
    assert named["kind"] == "payload" and named["joint"] is None
    assert named["parameters"]["mass"] == pytest.approx(truth["parameters"]["mass"], rel=truth["rtol"])
    n = len(nom["rms_validate"])
    assert _rms(named["rms_validate_after"], range(n)) <= 0.5 * _rms(nom["rms_validate"], range(n))
    # the projection helper agrees with the named mass
    reg = load_regressor(truth["robot"])
    theta = np.array([rep["baseline"]["parameters"][nm] for nm in reg.base_names])
    data = load(truth["fit_csv"], robot=truth["robot"])
    m = make_effect("payload", robot=truth["robot"]).mass_from_base_shift(data, reg, theta)
    assert m == pytest.approx(named["parameters"]["mass"], rel=0.05)


def test_no_hidden_effect_no_claim(tmp_path_factory):
    """Control: the true plant is exactly the baseline's structure -> repair adds nothing."""
    rep, _ = _run("none", tmp_path_factory)
    assert rep["effects"] == [], [e["label"] for e in rep["effects"]]
    assert not rep["nominal"]["significant"] and not rep["nominal"]["unexplained_shift"]


@pytest.mark.parametrize("kind", ["time_delay", "rotor_inertia", "spring"])
def test_replay_through_augmented_plant_improves(kind, tmp_path_factory):
    """The chosen effect added to the Drake plant (delay line / reflected inertia / force block):
    replaying the validation torques from measured states tracks the measured motion better."""
    out = tmp_path_factory.mktemp(f"replay_{kind}")
    fit, val, truth = hidden_effect_case(kind, seed=0, out_dir=str(out))
    opts = repair.RepairOptions(robot=truth["robot"], consistent=False, replay=True, replay_windows=10,
                                plots=False)
    rep = repair.run_repair([fit], opts, validate_paths=[val])
    assert rep["effects"] and rep["effects"][0]["kind"] == kind
    before, after = rep["replay"]["before"]["rms_q"], rep["replay"]["after"]["rms_q"]
    for j in range(len(before)):
        assert after[j] <= 0.3 * before[j], (kind, before, after)


def test_undeclared_sensor_vibration_is_caught_by_the_estimator_test(tmp_path_factory):
    """Errors in variables nobody declared: the plant is exact, but the *measured* positions carry
    a 5-8 Hz vibration (1 mrad RMS) the torque does not cause. Least squares on the differentiated
    positions is attenuated; repair detects it (Hausman + the fit-data replay), and the IV estimate
    lands within 3 % of the true inertial parameters; no torque effect is claimed for it. The IV
    switch is then held to the per-joint torque rule and kept: its validation torque is not worse
    beyond the paired test's spread (see below)."""
    from robust_drake.identification.least_squares import load_regressor
    from robust_drake.synthetic.simulated import hidden_effect_case

    out = tmp_path_factory.mktemp("hidden_vibration")
    fit, val, truth = hidden_effect_case("sensor_vibration", seed=0, out_dir=str(out), vibration_rms=1e-3)
    rep = repair.run_repair([fit], repair.RepairOptions(robot=truth["robot"], plots=False), validate_paths=[val])
    est = rep["estimator"]
    assert est["hausman"]["significant"]
    assert est["replay_fit"]["ratio"] < 0.5
    # IV's parameters are right, but with equally noisy validation columns its torque error is
    # above LS's on joint 0 (measured +7 %). Before issue 21 the never-worse rule (1 % on the point
    # RMS) dropped the switch for it; the paired block test finds +7.1 % [-20.6, +28.9] (95 %, 9
    # blocks): not worse beyond its spread, so IV stays -- and the replay of the validation data,
    # which does not suffer the noisy columns, says IV is much better (-73 % and -93 %, measured)
    iv_val, ls_val = est["baseline_iv"]["rms_validate"], rep["baseline"]["rms_validate"]
    assert iv_val[0] > 1.01 * ls_val[0], (iv_val, ls_val)
    assert est["method"] == "instrumental_variables"
    assert not any(d["kind"] == "estimator" for d in rep["rejected_effects"])
    assert rep["effects"] == [], [e["label"] for e in rep["effects"]]
    assert not any(t["worse"] for t in rep["final"]["validate_change"])
    assert all(t["better"] for t in rep["replay"]["after"]["tests"]), rep["replay"]["after"]["tests"]
    # the IV estimate itself is within 3 % of the true parameters
    from robust_drake.identification.data import load, load_companion
    from robust_drake.identification.instruments import INSTRUMENT_RATIO, fit_model_iv
    from robust_drake.model_repair.selection import ColumnCache

    reg = load_regressor(truth["robot"])
    data = load([fit], robot=truth["robot"])
    z = load_companion([fit], data, cutoff_hz=data.filter.cutoff_hz * INSTRUMENT_RATIO)
    iv, _ = fit_model_iv(ColumnCache(data, reg), ColumnCache(z, reg), [], np.ones(data.n))
    th0 = reg.base_parameters()
    big = [k for k in range(len(th0)) if abs(th0[k]) > 0.02]  # first moments and link inertias
    assert max(abs(iv.theta[k] / th0[k] - 1) for k in big) < 0.03
    # and the LS baseline it replaces is the attenuated one
    ls = [rep["baseline"]["parameters"][reg.base_names[k]] for k in big]
    assert max(abs(v / th0[k] - 1) for v, k in zip(ls, big)) > 0.09
