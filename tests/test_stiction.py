"""Stiction handled explicitly (issue 13): where a joint sticks, friction balances whatever torque
is applied and is not a function of velocity, so those rows (widened by the zero-phase filter's
settling time) are left out of that joint's equation in the velocity-friction fit
(``data.friction_exclusion`` -> ``fitting.ColumnCache(exclude=...)``), and the stick is reported
once per file and joint."""

import warnings

import numpy as np
import pytest

from robust_drake.identification import data as D
from robust_drake.identification.fitting import ColumnCache, fit_model

FC, FV = 0.8, 0.3  # N m, N m s/rad


class NoRigidBody:
    """A regressor without rigid-body columns: the model is the Coulomb + viscous friction alone."""

    base_names: list = []

    def evaluate(self, q, qd, qdd):
        return np.zeros(np.shape(q) + (0,))


def stick_slip(T=1.6, H=0.4, cycles=12, dt=4e-3):
    """One joint moving back and forth (half sines of 1.5 rad/s peak); at every reversal it holds
    still for ``H`` seconds while its torque swings from +F_c to -F_c (static friction holds it);
    while it moves the torque is exactly F_c sgn(qd) + F_v qd."""
    vs, taus = [], []
    for k in range(cycles):
        s = 1.0 if k % 2 == 0 else -1.0
        tm = np.arange(int(round(T / dt))) * dt
        v = s * 1.5 * np.sin(np.pi * tm / T)
        vs.append(v)
        taus.append(FC * np.sign(v) + FV * v)
        nh = int(round(H / dt))
        vs.append(np.zeros(nh))
        taus.append(np.linspace(s * FC, -s * FC, nh))
    v, tau = np.concatenate(vs), np.concatenate(taus)
    t = np.arange(len(v)) * dt
    return t, (np.cumsum(v) * dt)[:, None], tau[:, None]


def _fit(data, exclude):
    fit, _ = fit_model(ColumnCache(data, NoRigidBody(), exclude=exclude), [], np.ones(1))
    return dict(zip(fit.names, fit.theta)), fit


def test_stuck_rows_are_left_out_of_the_friction_fit():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", D.DataWarning)
        data = D.from_arrays(*stick_slip())
    assert 0.15 < data.stuck[:, 0].mean() < 0.25  # the holds are found
    exclude = D.friction_exclusion(data)
    assert exclude[data.stuck].all() and exclude.mean() > data.stuck.mean()  # widened by the filter
    naive, _ = _fit(data, None)
    kept, fit = _fit(data, exclude)
    # with the stuck rows the friction law is wrong (the holds pull F_c down, F_v up) ...
    assert abs(naive["fc1"] - FC) > 0.1 * FC and abs(naive["fv1"] - FV) > 0.2 * FV
    # ... without them it is the truth, and what is left is the filter's edge effects only
    assert kept["fc1"] == pytest.approx(FC, rel=0.01) and kept["fv1"] == pytest.approx(FV, rel=0.02)
    assert fit.rms[0] < 0.01 * FC


def test_stick_is_reported_once_per_file_and_joint_by_number_and_name(tmp_path):
    t, q, tau = stick_slip()
    path = D.write_canonical_csv(str(tmp_path / "s.csv"), t, q, tau)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", D.DataWarning)
        d = D.load(path, joint_names=["elbow"])
        D.load_companion(path, d, cutoff_hz=4.0)  # a second load at another cut-off: silent
    sticks = [str(w.message) for w in caught if "sticks" in str(w.message)]
    assert len(sticks) == 1, sticks
    assert "joint 1 (elbow) sticks" in sticks[0] and "q1" not in sticks[0]
    msgs = D.exclusion_messages(d, D.friction_exclusion(d), ["elbow"])
    assert len(msgs) == 1 and msgs[0].startswith("stiction: joint 1 (elbow)")
