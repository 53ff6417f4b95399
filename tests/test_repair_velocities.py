"""``robust-drake repair --velocities logged``: the log's velocity columns instead of the
positions' derivative (identification.data.prepare), and a one-line error without them.

The simulated arm (DFKI C.1 URDF, simulated.simulate_experiment) logs its true velocities with
``include_velocity=True``; positions carry 14-bit encoder quantisation and the torque 5 mN m
noise, so both routes must give a baseline of the same quality (measured 12 s, 250 Hz: RMS
validation 4.5 / 3.1 mN m differentiated, 3.0 / 2.7 mN m logged)."""

import json

import numpy as np
import pytest

from robust_drake import cli

ROBOT = "dfki_double_pendulum_c1"
QUICK = ["--no-replay", "--no-consistent", "--no-instruments", "--no-nominal", "--no-plots",
         "--max-effects", "0"]


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    from robust_drake.synthetic.simulated import simulate_experiment

    d = tmp_path_factory.mktemp("vel")
    paths = {k: str(d / f"{k}.csv") for k in ("fit", "val", "val_noqd")}
    simulate_experiment(ROBOT, duration=12.0, seed=0, out_csv=paths["fit"], include_velocity=True)
    simulate_experiment(ROBOT, duration=12.0, seed=1, out_csv=paths["val"], include_velocity=True)
    simulate_experiment(ROBOT, duration=12.0, seed=1, out_csv=paths["val_noqd"])
    return paths


def _baseline(sim, tmp_path, capsys, velocities):
    status = cli.main(["repair", sim["fit"], "--robot", ROBOT, "--validate", sim["val"], "--out",
                       str(tmp_path / velocities), "--json", "--velocities", velocities, *QUICK])
    out, err = capsys.readouterr()
    assert status == 0, err
    return np.array(json.loads(out)["baseline"]["rms_validate"])


def test_logged_velocities_give_a_baseline_like_the_differentiated_one(sim, tmp_path, capsys):
    diff = _baseline(sim, tmp_path, capsys, "differentiated")
    logged = _baseline(sim, tmp_path, capsys, "logged")
    # torque noise is 5 mN m: both baselines at the noise level, within a factor 2 of each other
    assert np.all(diff < 0.01) and np.all(logged < 0.01), (diff, logged)
    assert np.all(logged < 2 * diff) and np.all(diff < 2 * logged), (diff, logged)
    assert not np.allclose(logged, diff, rtol=0.02), (diff, logged)  # the logged columns were used


def test_logged_velocities_without_columns_is_a_one_line_error(sim, tmp_path, capsys):
    status = cli.main(["repair", sim["fit"], "--robot", ROBOT, "--validate", sim["val_noqd"], "--out",
                       str(tmp_path / "o"), "--velocities", "logged", *QUICK])
    _, err = capsys.readouterr()
    assert status == 2 and "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(lines) == 1 and "val_noqd.csv" in lines[0] and "qd1..qd2" in lines[0], err
