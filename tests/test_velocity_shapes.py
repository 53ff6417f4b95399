"""Friction shapes judged where the velocity resolves them (issue 21: "smooth Coulomb on sticking
wrist joints ... is claimed as arm physics").

The truth is the simulator's: the UR5 battery's no-effect arm has Coulomb friction with a
0.01 rad/s tanh (``synthetic.simulated.TRUE_FRICTION_V_EPS``) and no smooth Coulomb of 0.1-1
rad/s. Near a velocity reversal the joint sticks for a moment (shorter than the stuck-row rule)
and the 8 Hz filter spreads the Coulomb step, which a gradual switch imitates. Expectations of
the row rule are counted here from the sine's own zero crossings.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.signal import butter, filtfilt

from robust_drake.identification import conditioning as C
from robust_drake.identification.data import filter_main_lobe_s, reversal_half_width_s, reversal_rows


def test_filter_main_lobe_is_about_half_a_cutoff_period():
    """The first zero of the 8 Hz order-4 filtfilt impulse response, found here on scipy's own
    impulse response, is near 1 / (2 f_c) = 62.5 ms at every rate."""
    for fs in (100.0, 500.0, 2500.0):
        b, a = butter(4, 8.0 / (fs / 2))
        x = np.zeros(int(4 * fs) + 1)
        x[len(x) // 2] = 1.0
        h = filtfilt(b, a, x)[len(x) // 2:]
        first_zero = np.argmax(h <= 0) / fs
        assert filter_main_lobe_s(1 / fs, 8.0, 4) == pytest.approx(first_zero, abs=1.01 / fs)
        assert 0.055 < first_zero < 0.075
    assert filter_main_lobe_s(0.002, None) == 0.0


def _data(qd, dt, segment, stuck=None):
    N = len(qd)
    return SimpleNamespace(qd=qd[:, None], N=N, n=1, dt=dt, segment=segment, stuck=stuck,
                           filter=SimpleNamespace(cutoff_hz=8.0, order=4, derivatives="computed"),
                           segment_period=lambda s: dt)


def test_reversal_rows_are_the_rows_near_each_zero_crossing_within_its_segment():
    dt, f = 0.002, 0.3
    t = np.arange(0.0, 10.0, dt)
    qd = np.sin(2 * np.pi * f * t + 0.4)
    seg = (t >= 5.0).astype(int)  # a gap at 5 s: two segments
    stuck = np.zeros((len(t), 1), bool)
    stuck[100:130, 0] = True
    data = _data(qd, dt, seg, stuck)
    w = reversal_half_width_s(data)
    assert w == pytest.approx(0.5 * C.STICK_MIN_S + filter_main_lobe_s(dt, 8.0, 4))
    got = reversal_rows(data, 0)
    # expected: rows within w of a sign change inside the same segment, plus the stuck rows
    expect = stuck[:, 0].copy()
    for s in (0, 1):
        idx = np.nonzero(seg == s)[0]
        v = qd[idx]
        crossings = [idx[0] + k + 0.5 for k in range(len(v) - 1) if (v[k] > 0) != (v[k + 1] > 0)]
        for c in crossings:
            near = np.abs(idx - c) * dt < w
            expect[idx[near]] = True
    assert np.mean(got != expect) < 2e-3  # rounding of w to whole samples at the window edges
    assert got[np.abs(qd) > 0.99].sum() == 0  # nowhere near the peaks
    # a segment boundary is not a reversal: no window opens at 5 s (the sine is at 0.80 there)
    assert not got[(t > 4.95) & (t < 5.05)].any()
    # the share: 2 reversals per period, each 2 w wide
    assert got[~stuck[:, 0]].mean() == pytest.approx(2 * f * 2 * w, rel=0.1)


@pytest.fixture(scope="module")
def clean_no_effect_repair(tmp_path_factory):
    """The UR5 battery's no-effect case at 500 Hz (seed 112, 10 s runs) with the torque noise
    switched off: what remains is the plant's own sticking at reversals."""
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair
    from robust_drake.synthetic import arm_battery as AB

    sim = AB.ARM_SIM["ur5"]
    old = sim["rel"], sim["floor"]
    sim["rel"], sim["floor"] = 0.0, (1e-3,) * 6
    try:
        fits, vals, truth = AB.generate("ur5", "none", out_dir=str(tmp_path_factory.mktemp("clean")), rate_hz=500.0,
                                        duration=10.0, seed=112)
    finally:
        sim["rel"], sim["floor"] = old
    return run_repair(fits, RepairOptions(robot=truth["fit_robot"], consistent=False, replay=False, plots=False),
                      validate_paths=vals)


@pytest.mark.slow
def test_sticking_at_reversals_is_not_claimed_as_a_smooth_coulomb(clean_no_effect_repair):
    """Measured: the selection finds smooth_coulomb on joints 1, 2 and 6 (joint 2's validation
    -10.3 % [-11.9, -8.8], all of it within 0.1 s of a reversal); fitted and validated away from the
    reversals none is a significant gain, so none is kept and the reason says where the gain sat."""
    rep = clean_no_effect_repair
    assert not [e for e in rep["effects"] if e["kind"] == "smooth_coulomb"], rep["effects"]
    shapes = [d for d in rep["rejected_effects"] if d.get("rule") == "velocity_shape"]
    assert shapes, "the selection found no smooth Coulomb here: this test no longer tests the rule"
    for d in shapes:
        assert d["kind"] == "smooth_coulomb" and "velocity reversals" in d["reason"]
        t = d["tests"][0]
        assert not t["better"] and t["blocks"] >= 4 and math.isfinite(t["low"])
    assert "not a significant gain on its joint" in rep["verdict_reason"]


def test_a_cache_excluding_more_rows_equals_one_built_with_them(tmp_path):
    """``ColumnCache.excluding`` (a masked copy) against a cache built from scratch with the
    union of the exclusions: the same columns, torques and fitted parameters."""
    import pandas as pd
    from fourier_motion import fourier_motion

    from robust_drake.effects import SmoothCoulomb
    from robust_drake.identification.data import load
    from robust_drake.identification.fitting import ColumnCache, fit_model
    from robust_drake.identification.least_squares import load_regressor

    robot = "dfki_double_pendulum_c1"
    reg = load_regressor(robot)
    t = np.arange(0.0, 6.0, 0.005)
    q, qd, qdd = fourier_motion(t, np.random.default_rng(3), 0.25)
    tau = reg.evaluate(q, qd, qdd) @ reg.base_parameters() + 0.08 * np.sign(qd) + 0.004 * qd
    tau += 0.005 * np.random.default_rng(4).standard_normal(tau.shape)
    path = tmp_path / "log.csv"
    pd.DataFrame({"t": t, "q1": q[:, 0], "q2": q[:, 1], "tau1": tau[:, 0], "tau2": tau[:, 1]}).to_csv(path, index=False)
    data = load([str(path)], robot=robot, n_joints=2)
    first = np.zeros((data.N, 2), bool)
    first[:100, 0] = True
    extra = np.zeros((data.N, 2), bool)
    extra[:, 1] = reversal_rows(data, 1)
    assert extra[:, 1].any()
    copy = ColumnCache(data, reg, exclude=first).excluding(extra)
    fresh = ColumnCache(data, reg, exclude=first | extra)
    effects = [SmoothCoulomb(1, transition_velocity=0.1)]
    assert np.array_equal(copy.model(effects)[0], fresh.model(effects)[0])
    assert np.array_equal(copy.data.tau, fresh.data.tau) and np.array_equal(copy.rows, fresh.rows)
    a, b = fit_model(copy, effects)[0], fit_model(fresh, effects)[0]
    assert np.allclose(a.theta, b.theta, rtol=1e-10, atol=1e-12)
