"""Effects outside the original library (issue 13): diagnostics, new kinds, battery.

Arms other than the D2R2 / the default C.1 arm (``simulated_cases.ARMS``: the DFKI A.0 double
pendulum, the Siciliano 2-link vertical arm (50 kg links) and the 7-joint ``serial7`` (slow),
noise and effect sizes scaled with the torques).
Each case hides one block no original kind represents (``simulated_cases.OUTSIDE_CASES``):
a 3.1 Hz and a 0.73 Hz torque periodic in time, a driver dead-zone, a viscous coefficient that
grows over the run. The battery runs ``repair`` (Python API) and asserts:
  - flagged: ``unexplained_structure`` with the right test (periodic / dead_band / drift) on the
    right joint (and the frequency within 2 %) in the final residual's ``where``, or in the
    baseline residual's diagnostics when an added effect absorbed it (serial7 drift);
  - nothing claimed with high confidence except the outside effect named by its own kind, and
    no ``time_delay`` / ``position_dependent`` / ``rotor_inertia`` / ``spring`` claimed at all;
  - never worse: no joint's final validation RMS above the baseline's by more than 1 % beyond the
    paired block test's spread (the report's ``final.validate_change``; the IV switch included);
  - the no-effect case: nothing claimed, nothing flagged.
The new kinds are fitted directly (baseline + the candidates the diagnostics propose) and their
parameters recovered within stated tolerances. ~5 s per case (12 s runs at 250 Hz).
"""

from types import SimpleNamespace

import numpy as np
import pytest

from robust_drake.model_repair import diagnostics as D
from robust_drake.effects import DIAGNOSTIC_KINDS, all_candidates, make_effect
from robust_drake.synthetic.simulated_cases import outside_case

repair = pytest.importorskip("robust_drake.model_repair.pipeline")

ROBOTS = ["dfki_double_pendulum_a0", "siciliano_2link",
          pytest.param("serial7", marks=pytest.mark.slow)]  # 7 joints: ~15-25 s per repair
CASES = ["periodic_fast", "periodic_slow", "dead_zone", "drift"]
EXPECTED_TEST = {"periodic_fast": "periodic", "periodic_slow": "periodic", "dead_zone": "dead_band",
                 "drift": "drift"}
MISATTRIBUTED = {"time_delay", "position_dependent", "rotor_inertia", "spring"}

_CACHE: dict = {}


def _case(robot, case, tmp_path_factory):
    key = (robot, case)
    if key not in _CACHE:
        out = tmp_path_factory.mktemp(f"{robot}_{case}")
        fit, val, truth = outside_case(case, robot=robot, out_dir=str(out))
        _CACHE[key] = (fit, val, truth)
    return _CACHE[key]


def _repair(robot, case, tmp_path_factory):
    key = ("repair", robot, case)
    if key not in _CACHE:
        fit, val, truth = _case(robot, case, tmp_path_factory)
        opts = repair.RepairOptions(robot=robot, consistent=False, replay=False, plots=False)
        _CACHE[key] = (repair.run_repair([fit], opts, validate_paths=[val]), truth)
    return _CACHE[key]


# ------------------------------------------------------------------------------ blocks = columns
def _eval_block(blk, q, qd, tau=None, t=0.0):
    ctx = blk.CreateDefaultContext()
    ctx.SetTime(t)
    blk.GetInputPort("state").FixValue(ctx, np.concatenate([q, qd]))
    if blk.HasInputPort("tau"):
        blk.GetInputPort("tau").FixValue(ctx, np.asarray(tau, float))
    return blk.GetOutputPort("generalized_force").Eval(ctx)


RNG = np.random.default_rng(3)
Q, QD, TAU = RNG.normal(size=(20, 2)), RNG.normal(size=(20, 2)), RNG.normal(scale=0.3, size=(20, 2))
T = np.linspace(0.0, 9.0, 20)


@pytest.mark.parametrize("joint", [0, 1])
def test_periodic_disturbance_block_is_the_sinusoid_and_minus_columns(joint):
    A, f, phi = 0.08, 3.1, 0.3
    eff = make_effect("periodic_disturbance", joint, frequency=f)
    params = {"amplitude": A, "phase": phi}
    coef = eff.coef_from_parameters(params, 2)
    blk = eff.block(2, params)
    cols, _ = eff.columns(SimpleNamespace(t=T, q=Q, qd=QD, qdd=0 * Q, tau=TAU))
    for i in range(len(T)):
        out = _eval_block(blk, Q[i], QD[i], t=T[i])
        expected = np.zeros(2)
        expected[joint] = A * np.sin(2 * np.pi * f * T[i] + phi)  # the disturbance on the joint
        np.testing.assert_allclose(out, expected, atol=1e-12)
        np.testing.assert_allclose(cols[i] @ coef, -out, atol=1e-12)
    back = eff.parameters(coef)
    assert back["amplitude"] == pytest.approx(A) and back["phase"] == pytest.approx(phi)
    assert eff.is_disturbance


@pytest.mark.parametrize("joint", [0, 1])
def test_dead_zone_block_loses_the_torque_below_threshold(joint):
    d = 0.2
    eff = make_effect("dead_zone", joint, threshold=d)
    blk = eff.block(2, {"share": 1.0})
    cols, _ = eff.columns(SimpleNamespace(t=T, q=Q, qd=QD, qdd=0 * Q, tau=TAU))
    for i in range(len(T)):
        out = _eval_block(blk, Q[i], QD[i], TAU[i])
        applied = TAU[i] + out
        u = TAU[i, joint]
        assert applied[joint] == pytest.approx(0.0 if abs(u) <= d else u - d * np.sign(u), abs=1e-12)
        assert applied[1 - joint] == pytest.approx(TAU[i, 1 - joint], abs=1e-12)
        np.testing.assert_allclose(cols[i] @ [1.0], -out, atol=1e-12)
    # the inverse dead-zone: the commanded torque that makes the joint receive m
    m = np.linspace(-1, 1, 41)
    for c in (0.6, 1.0):
        tau = eff.commanded_torque(m, [c])
        np.testing.assert_allclose(tau - c * np.clip(tau, -d, d), m, atol=1e-12)


@pytest.mark.parametrize("joint", [0, 1])
def test_friction_drift_block_is_a_growing_viscous_term(joint):
    r = 0.004
    eff = make_effect("friction_drift", joint)
    params = {"viscous_rate": r, "coulomb_rate": 0.0}
    blk = eff.block(2, params)
    coef = eff.coef_from_parameters(params, 2)
    cols, _ = eff.columns(SimpleNamespace(t=T, q=Q, qd=QD, qdd=0 * Q, tau=TAU))
    for i in range(len(T)):
        out = _eval_block(blk, Q[i], QD[i], t=T[i])
        assert out[joint] == pytest.approx(-r * T[i] * QD[i, joint], abs=1e-12)
        np.testing.assert_allclose(cols[i] @ coef, -out, atol=1e-12)


def test_diagnostic_kinds_are_offered_only_where_a_diagnostic_fired():
    assert all_candidates(2, kinds=DIAGNOSTIC_KINDS) == []
    rows = [{"test": "periodic", "joint": 1, "frequency_hz": 3.1}, {"test": "drift", "joint": 0},
            {"test": "dead_band", "joint": 1, "threshold": 0.15}]
    c = all_candidates(2, kinds=DIAGNOSTIC_KINDS, diagnostics=rows)
    assert sorted((e.kind, e.joint) for e in c) == sorted(
        [("periodic_disturbance", 1), ("friction_drift", 0)] + [("dead_zone", 1)] * 3)


# ------------------------------------------------------------------------------ recovery
def _fit_diagnostic_kinds(fit_csv, robot):
    from robust_drake.identification.data import load
    from robust_drake.identification.least_squares import load_regressor
    from robust_drake.model_repair.selection import ColumnCache, fit_model

    data = load(fit_csv, robot=robot)
    cache = ColumnCache(data, load_regressor(robot))
    base, _ = fit_model(cache, [])
    rows = D.diagnose(data, base.residual)
    best = None
    for e in all_candidates(data.n, kinds=DIAGNOSTIC_KINDS, diagnostics=rows):
        f, sl = fit_model(cache, [e])
        rss = float(np.sum(f.residual ** 2))
        if best is None or rss < best[0]:
            best = (rss, e, e.parameters(f.theta[sl[0]]), f)
    return rows, best, base


TOL = {"periodic_fast": ("amplitude", 0.15), "periodic_slow": ("amplitude", 0.15),
       "dead_zone": ("threshold", 0.25), "drift": ("viscous_rate", 0.25)}


@pytest.mark.parametrize("case", CASES)
def test_new_kind_recovers_the_hidden_effect(case, tmp_path_factory):
    robot = ROBOTS[0]
    fit, _, truth = _case(robot, case, tmp_path_factory)
    rows, best, base = _fit_diagnostic_kinds(fit, robot)
    assert best is not None, rows
    _, eff, params, f = best
    assert (eff.kind, eff.joint) == (truth["kind"], truth["joint"]), (eff, rows)
    key, rtol = TOL[case]
    est = params[key] if key in params else eff.shape[key]
    assert est == pytest.approx(truth["parameters"][key], rel=rtol), (params, eff.shape)
    if eff.kind == "periodic_disturbance":
        assert eff.shape["frequency"] == pytest.approx(truth["parameters"]["frequency"], rel=0.01)
    if eff.kind == "dead_zone":
        assert 0.7 <= params["share"] <= 1.3, params
    # the fitted kind explains most of the affected joint's residual
    j = truth["joint"]
    assert f.rms[j] <= 0.5 * base.rms[j], (f.rms, base.rms)


# ------------------------------------------------------------------------------ battery
@pytest.mark.parametrize("robot", ROBOTS)
def test_no_effect_nothing_claimed_nothing_flagged(robot, tmp_path_factory):
    rep, _ = _repair(robot, "none", tmp_path_factory)
    assert rep["effects"] == [], [e["label"] for e in rep["effects"]]
    assert rep["unexplained_structure"] is False, rep["unexplained_where"]


@pytest.mark.parametrize("robot", ROBOTS)
@pytest.mark.parametrize("case", CASES)
def test_outside_effect_is_flagged_where_it_sits(robot, case, tmp_path_factory):
    rep, truth = _repair(robot, case, tmp_path_factory)

    def hits(rows):
        return [w for w in rows if w.get("test") == EXPECTED_TEST[case] and w["joint"] == truth["joint"]]

    # the baseline residual's diagnostics fire on the right joint (that is what offers the new
    # kinds to the selection); when the selection then names the outside effect with its own kind
    # the final residual may be clean, otherwise the final residual is flagged there too
    named = [e for e in rep["effects"] if (e["kind"], e["joint"]) == (truth["kind"], truth["joint"])]
    found = hits(rep["residual"]["baseline"]["diagnostics"])
    assert found, rep["residual"]["baseline"]["diagnostics"]
    if not named:
        assert rep["unexplained_structure"] is True
    if EXPECTED_TEST[case] == "periodic":
        assert found[0]["frequency_hz"] == pytest.approx(truth["parameters"]["frequency"], rel=0.02)
    others = [e for e in rep["effects"] if e not in named]
    assert all(e["confidence"] != "high" for e in others), rep["effects"]


def _cases(cases, known_failures, reason):
    """(robot, case) pairs; the measured failures marked xfail with the reason, the rest strict."""
    out = []
    for r in ROBOTS:
        name, marks = (r.values[0], list(r.marks)) if hasattr(r, "values") else (r, [])
        for c in cases:
            m = marks + ([pytest.mark.xfail(strict=False, reason=reason)] if (name, c) in known_failures else [])
            out.append(pytest.param(name, c, marks=m, id=f"{c}-{name}"))
    return out


@pytest.mark.parametrize("robot,case", _cases(CASES, set(), ""))
def test_outside_effect_not_misattributed(robot, case, tmp_path_factory):
    rep, _ = _repair(robot, case, tmp_path_factory)
    assert not [e["label"] for e in rep["effects"] if e["kind"] in MISATTRIBUTED]


@pytest.mark.parametrize("robot,case", _cases(["none"] + CASES, set(), ""))
def test_never_worse(robot, case, tmp_path_factory):
    """Worse = worse beyond the paired block test's spread by more than the 1 % margin (issue 21);
    before it: the point RMS within 1 %, which serial7's kept IV switch misses on joint 6 by
    +1.3 % [+0.5, +2.0] (95 %) in the no-effect case."""
    rep, _ = _repair(robot, case, tmp_path_factory)
    before = np.array(rep["baseline"]["rms_validate"])
    tests = rep["final"]["validate_change"]
    assert len(tests) == len(before)
    assert not [(j, t) for j, t in enumerate(tests) if t["worse"]]


# ------------------------------------------------------------------------------ pure diagnostics
def _synthetic(seconds=20.0, rate=250.0, seed=0):
    """Data-like object: two joints moving at 0.2 and 0.3 Hz, 8 Hz analysis filter."""
    t = np.arange(0.0, seconds, 1.0 / rate)
    qd = np.column_stack([np.cos(2 * np.pi * 0.2 * t), 0.7 * np.cos(2 * np.pi * 0.3 * t)])
    tau = np.column_stack([np.sin(2 * np.pi * 0.2 * t), 0.5 * np.sin(2 * np.pi * 0.3 * t)])
    noise = np.random.default_rng(seed).normal(scale=0.005, size=(len(t), 2))
    return SimpleNamespace(t=t, qd=qd, tau=tau, dt=1.0 / rate, N=len(t), n=2,
                           segment=np.zeros(len(t), int), filter=SimpleNamespace(cutoff_hz=8.0)), noise


def test_periodic_peak_found_at_its_frequency_and_not_at_a_motion_line():
    data, noise = _synthetic()
    r = noise.copy()
    r[:, 1] += 0.05 * np.sin(2 * np.pi * 2.3 * data.t + 0.4)
    (row,) = D.periodic_peaks(data, r)
    assert row["joint"] == 1 and row["frequency_hz"] == pytest.approx(2.3, rel=0.005)
    assert row["amplitude"] == pytest.approx(0.05, rel=0.1)
    assert D.periodic_peaks(data, noise) == []
    # a model error at the motion's own frequency (e.g. a wrong inertia) is the motion's, not a
    # disturbance, however strong
    r = noise.copy()
    r[:, 0] += 0.05 * np.sin(2 * np.pi * 0.2 * data.t)
    assert D.periodic_peaks(data, r) == []


def test_drift_and_dead_band_fire_only_on_their_structure():
    data, noise = _synthetic()
    r = noise.copy()
    r[:, 0] += 0.002 * data.t * data.qd[:, 0]  # viscous coefficient growing 2 mN m s/rad per s
    (row,) = D.friction_drift(data, r)
    assert row["joint"] == 0 and row["coefficient"] == "viscous"
    assert row["last_third"] - row["first_third"] == pytest.approx(0.002 * 2 / 3 * 20.0, rel=0.15)
    assert D.friction_drift(data, noise) == []
    assert D.dead_band(data, r) == []  # a drift is no dead-band
    r = noise.copy()
    r[:, 1] += np.clip(data.tau[:, 1], -0.1, 0.1)  # torque below 0.1 N m lost
    rows = D.dead_band(data, r)
    assert [w["joint"] for w in rows] == [1]
    assert rows[0]["threshold"] == pytest.approx(0.1, rel=0.25)
    assert D.friction_drift(data, r) == []
    assert D.dead_band(data, noise) == []


def test_generalization_flags_a_validation_much_worse_than_the_fit():
    fit = np.full((100, 2), 0.01)
    val = np.column_stack([np.full(100, 0.011), np.full(100, 0.03)])
    assert [w["joint"] for w in D.generalization(fit, val)] == [1]


# ------------------------------------------------------------------------------ the selection hook
@pytest.mark.parametrize("case", CASES)
def test_selection_given_the_diagnostic_candidates_names_the_outside_effect(case, tmp_path_factory):
    """The hook the repair selection uses (stages.select_effects): candidates =
    ``all_candidates(n, robot=..., diagnostics=diagnose(fit, baseline residual))``, searched by
    the existing ``forward_select``. The outside effect is then named first, on its joint, nothing
    misattributed, and no joint's validation gets worse (A.0 cases)."""
    from robust_drake.identification.data import load
    from robust_drake.identification.least_squares import load_regressor
    from robust_drake.model_repair.selection import ColumnCache, fit_model, forward_select, predict_tau

    robot = ROBOTS[0]
    fit, val, truth = _case(robot, case, tmp_path_factory)
    reg = load_regressor(robot)
    cf, cv = ColumnCache(load(fit, robot=robot), reg), ColumnCache(load(val, robot=robot), reg)
    base, _ = fit_model(cf, [])
    cands = all_candidates(cf.data.n, robot=robot, diagnostics=D.diagnose(cf.data, base.residual))
    chosen = forward_select(cf, cands).chosen
    assert chosen and (chosen[0].kind, chosen[0].joint) == (truth["kind"], truth["joint"]), chosen
    assert not [e.name for e in chosen if e.kind in MISATTRIBUTED]
    final, _ = fit_model(cf, chosen)
    rms = lambda r: np.sqrt(np.mean(r ** 2, axis=0))  # noqa: E731
    before = rms(cv.data.tau - predict_tau(cv, [], base.theta))
    after = rms(cv.data.tau - predict_tau(cv, chosen, final.theta))
    assert np.all(after <= before * 1.01), (before, after)
    j = truth["joint"]
    assert after[j] <= 0.5 * before[j], (before, after)


def test_admissibility_of_the_new_kinds():
    from robust_drake.effects import admissible

    dz = make_effect("dead_zone", 1, threshold=0.1)
    assert admissible(dz, {"share": 0.95}) == ""
    assert "share" in admissible(dz, {"share": 0.2})  # most of the band's torque arrives: no dead-zone
    dr = make_effect("friction_drift", 0)
    base = {"viscous": 0.004, "coulomb": 0.02}
    assert admissible(dr, {"viscous_rate": -0.0002, "coulomb_rate": 0.0}, base, duration=12.0) == ""
    # b = 0.004 - 0.001 * 12 < 0 at the end of the run: friction cannot feed energy in
    assert "viscous" in admissible(dr, {"viscous_rate": -0.001, "coulomb_rate": 0.0}, base, duration=12.0)
    pd = make_effect("periodic_disturbance", 1, frequency=0.05)
    assert "frequency" in admissible(pd, {"sin": 0.0, "cos": 0.0}, band_hz=(2 / 12.0, 8.0))
