"""Canonical CSV, DFKI adapter, validation errors and the filter/differentiation convention."""

import os

import numpy as np
import pandas as pd
import pytest

from robust_drake.errors import DataError
from robust_drake.identification import data as D

DFKI = os.path.join(os.environ.get("ROBUST_DRAKE_DATA")
                    or os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"), "dfki_double_pendulum")
C1 = os.path.join(DFKI, "design_C1")


def _sine_csv(path, f=1.0, dt=0.002, T=4.0, amp=0.5):
    t = np.arange(0, T, dt)
    w = 2 * np.pi * f
    q = np.column_stack([amp * np.sin(w * t), amp * np.cos(w * t)])
    tau = np.column_stack([np.cos(w * t), 2 * np.sin(w * t)])
    D.write_canonical_csv(path, t, q, tau)
    return t, q, tau, w


def test_derivatives_of_a_sine_match_calculus(tmp_path):
    """qd, qdd from filtered positions equal the analytic derivatives (f = 1 Hz << cut-off)."""
    p = tmp_path / "s.csv"
    t, q, tau, w = _sine_csv(p)
    d = D.load(str(p))
    m = d.filter.trim_samples
    assert m == round(2 / D.DEFAULT_CUTOFF_HZ / 0.002)  # 2 / cut-off seconds cut at each end
    tt = d.t
    qd_true = np.column_stack([0.5 * w * np.cos(w * tt), -0.5 * w * np.sin(w * tt)])
    qdd_true = -w**2 * np.column_stack([0.5 * np.sin(w * tt), 0.5 * np.cos(w * tt)])
    assert np.max(np.abs(d.qd - qd_true)) < 0.01 * 0.5 * w
    assert np.max(np.abs(d.qdd - qdd_true)) < 0.02 * 0.5 * w**2
    # zero phase: the filtered torque is not delayed (a 1 Hz sine at 8 Hz cut-off keeps its phase)
    assert np.max(np.abs(d.tau[:, 0] - np.cos(w * tt))) < 5e-3


def test_filter_removes_noise_above_cutoff_and_is_applied_to_tau(tmp_path):
    rng = np.random.default_rng(0)
    t = np.arange(0, 4, 0.002)
    hf = 0.01 * np.sin(2 * np.pi * 60 * t)  # 60 Hz, far above the cut-off
    q = np.column_stack([0.3 * np.sin(t) + hf, 0.2 * np.sin(2 * t)])
    tau = np.column_stack([np.sin(t) + hf, np.cos(t) + 0.001 * rng.standard_normal(len(t))])
    d = D.from_arrays(t, q, tau)
    k = d.filter.trim_samples
    assert np.max(np.abs(d.q[:, 0] - 0.3 * np.sin(t[k:-k]))) < 1e-3
    assert np.max(np.abs(d.tau[:, 0] - np.sin(t[k:-k]))) < 1e-3


@pytest.mark.parametrize("mutate, message", [
    (lambda df: df.drop(columns=["tau2"]), "torque"),
    (lambda df: df.assign(t=df.t.values[::-1]), "not strictly increasing"),
    (lambda df: df.assign(q1=np.where(np.arange(len(df)) == 100, np.nan, df.q1)), "NaN"),
    (lambda df: df.assign(q2=0.0), "constant"),
    (lambda df: df.assign(q1=np.degrees(df.q1) * 40), "degrees"),
    (lambda df: df.iloc[:20], "only 20 samples"),
    # a logging gap every 30 samples: every segment is too short for the filters (a few gaps
    # only split the file: tests/test_conditioning.py)
    (lambda df: df.assign(t=df.t.values + 0.05 * (np.arange(len(df)) // 30)), "too short"),
])
def test_validation_errors_are_clear(tmp_path, mutate, message):
    p = tmp_path / "s.csv"
    _sine_csv(p)
    df = mutate(pd.read_csv(p))
    bad = tmp_path / "bad.csv"
    df.to_csv(bad, index=False)
    with pytest.raises(DataError, match=message):
        D.load(str(bad))


def test_duplicate_columns_and_joint_count(tmp_path):
    p = tmp_path / "s.csv"
    _sine_csv(p)
    text = open(p).read().splitlines()
    text[0] = text[0].replace("tau2", "tau1")
    (tmp_path / "dup.csv").write_text("\n".join(text))
    with pytest.raises(DataError, match="duplicate"):
        D.load(str(tmp_path / "dup.csv"))
    with pytest.raises(DataError, match="robot has 3"):
        D.load(str(p), n_joints=3)
    (tmp_path / "x.csv").write_text("a,b\n1,2\n")
    with pytest.raises(DataError, match="unrecognised"):
        D.load(str(tmp_path / "x.csv"))


def test_jitter_is_reported(tmp_path):
    rng = np.random.default_rng(1)
    t = np.cumsum(0.002 * (1 + 0.1 * rng.standard_normal(2000)))
    q = np.column_stack([np.sin(t), np.cos(t)])
    d = D.from_arrays(t, q, q)
    assert d.jitter == pytest.approx(np.std(np.diff(t)) / np.mean(np.diff(t)), rel=1e-9)
    assert any("jitter" in w for w in d.warnings)


def test_segments_do_not_mix(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    _sine_csv(a, f=1.0)
    _sine_csv(b, f=0.5)
    d = D.load([str(a), str(b)])
    assert sorted(np.unique(d.segment)) == [0, 1]
    assert len(d.segments()) == 2 and d.segments()[1].N + d.segments()[0].N == d.N


@pytest.mark.skipif(not os.path.isdir(C1), reason="shared DFKI data not available")
def test_dfki_adapter_torque_choice():
    f = os.path.join(C1, "20230629-143339.csv")
    raw_m = D.read_csv(f, torque="tau_meas")
    raw_c = D.read_csv(f, torque="tau_con")
    df = pd.read_csv(f)
    assert raw_m.fmt == "dfki" and raw_m.n == 2
    np.testing.assert_array_equal(raw_m.tau, df[["tau_meas1", "tau_meas2"]].to_numpy())
    np.testing.assert_array_equal(raw_c.tau, df[["tau_con1", "tau_con2"]].to_numpy())
    assert raw_m.qd is None  # vel_meas (a raw finite difference) is recomputed, not used
    with pytest.raises(DataError, match="tau_meas"):
        D.read_csv(f, torque="tau_fric")
    d = D.load(f)
    # recomputed velocity agrees with the recorded finite difference at low frequency
    k = d.filter.trim_samples
    v_rec = D.zero_phase_lowpass(df[["vel_meas1", "vel_meas2"]].to_numpy(), d.dt, 8.0)[k:-k]
    assert np.sqrt(np.mean((d.qd - v_rec) ** 2)) < 0.05 * np.sqrt(np.mean(v_rec**2))
