"""The residual diagnostic for structure at torque reversals (backlash, issue 13).

``diagnostics.reversal`` looks for residual energy concentrated just after the sign changes of a
joint's torque: backlash (``synthetic.backlash``) leaves the link without drive torque while
the gap is crossed and then rings on the teeth. Synthetic residuals (30 s at 250 Hz, noise
low-passed at the data's 8 Hz cut-off like the parallel-filtered residual) check that it fires
on reversal-locked bursts of random phase on the right joint, stays silent on white noise and on
a (smoothed) Coulomb mismatch that steps at velocity reversals; a generated backlash log on the
Siciliano 2-link arm (8 s runs) checks the whole repair flags it, in report.json and report.md,
and that its no-effect log is not flagged.
"""

import os
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.signal import butter, filtfilt

from robust_drake.model_repair import diagnostics as D

FS, FC, T_END = 250.0, 8.0, 30.0


def _data(seed=0):
    t = np.arange(0.0, T_END, 1.0 / FS)
    # velocities and torques reverse at different times (torque ~ inertia x acceleration + load)
    qd = np.column_stack([np.sin(2 * np.pi * 0.31 * t), np.sin(2 * np.pi * 0.27 * t + 0.4)])
    tau = np.column_stack([np.sin(2 * np.pi * 0.23 * t + 1.0), np.sin(2 * np.pi * 0.19 * t + 2.0)])
    return SimpleNamespace(t=t, dt=1.0 / FS, N=len(t), n=2, segment=np.zeros(len(t), int), q=np.cumsum(qd, 0) / FS,
                           qd=qd, qdd=np.gradient(qd, 1.0 / FS, axis=0), tau=tau,
                           filter=SimpleNamespace(cutoff_hz=FC))


def _noise(rng, N, std):
    b, a = butter(4, FC / (FS / 2))
    x = filtfilt(b, a, rng.normal(size=(N, 2)), axis=0)
    return std * x / x.std(axis=0)


def _bursts(data, joint, amp, rng):
    """A decaying 6 Hz ring of random phase (its mean over reversals ~ 0) after every torque
    reversal of ``joint``, 0.3 s long."""
    out = np.zeros(data.N)
    for i in D.reversals(data.tau[:, joint], data.segment):
        k = np.arange(min(int(0.3 * FS), data.N - i))
        out[i:i + len(k)] += amp * np.exp(-k / (0.1 * FS)) * np.sin(2 * np.pi * 6.0 * k / FS + rng.uniform(0, 2 * np.pi))
    return out


def test_fires_on_reversal_locked_bursts_at_the_right_joint():
    rng = np.random.default_rng(1)
    data = _data()
    r = _noise(rng, data.N, 0.1)
    r[:, 1] += _bursts(data, 1, 2.0, rng)
    rows = D.reversal(data, r)
    assert [w["joint"] for w in rows] == [1]
    w = rows[0]
    assert w["test"] == "reversal" and w["eta2"] >= D.REVERSAL_SHARE and w["p"] < D.ALPHA
    assert w["window_s"] in D.REVERSAL_WIDTHS and "after torque reversals" in w["where"]
    assert [(w["test"], w["joint"]) for w in D.diagnose(data, r)] == [("reversal", 1)]


def test_silent_on_white_residual():
    rng = np.random.default_rng(2)
    data = _data()
    for _ in range(5):
        assert D.reversal(data, _noise(rng, data.N, 0.1)) == []


def test_silent_on_a_coulomb_mismatch_at_velocity_reversals():
    """A smoothed Coulomb level the baseline misses (2 N m, transition 0.05 rad/s): sign(qd)
    cannot absorb its smooth part, what is left steps at the velocity reversals."""
    rng = np.random.default_rng(3)
    data = _data()
    r = _noise(rng, data.N, 0.1) + 2.0 * np.tanh(data.qd / 0.05)
    assert D.reversal(data, r) == []
    # a joint whose torque reverses 32 ms after its velocity (viscous-dominated): the energy sits
    # after the torque reversals too (share ~0.5, ratio ~15), but as much after the velocity
    # reversals -- friction, not backlash: silent
    slow = SimpleNamespace(**{**vars(data), "tau": np.roll(data.qd, 8, axis=0)})
    assert D.reversal(slow, r) == []
    # the same residual with the bursts at the torque reversals of joint 0 added: found
    r[:, 0] += _bursts(data, 0, 4.0, rng)
    assert [w["joint"] for w in D.reversal(data, r)] == [0]


@pytest.fixture(scope="module")
def siciliano_backlash(tmp_path_factory):
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair
    from robust_drake.synthetic.simulated_cases import backlash_case

    out = tmp_path_factory.mktemp("backlash")
    fit, val, truth = backlash_case("siciliano_2link", out_dir=str(out / "logs"), duration=8.0, joint=1)
    opts = RepairOptions(robot="siciliano_2link", consistent=False, replay=False, plots=False)
    rep = run_repair([fit], opts, validate_paths=[val], out_dir=str(out / "report"))
    with open(os.path.join(out / "report", "report.md")) as fh:
        return rep, fh.read(), truth


def test_backlash_on_the_siciliano_elbow_is_flagged(siciliano_backlash):
    rep, md, truth = siciliano_backlash
    rows = [w for w in rep["unexplained_where"] if w["test"] == "reversal"]
    assert rep["unexplained_structure"] and [w["joint"] for w in rows] == [truth["joint"]]
    assert rows[0]["eta2"] >= D.REVERSAL_SHARE
    assert "tau2 reversals" in md and "unexplained_structure: true" in md
