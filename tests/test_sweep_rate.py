"""The sample-rate study proposed in JS section 11, on the simulated D2R2.

SP1, SP2 and ZC (table 1 epsilons, K = diag(30, 10), Lambda = diag(50, 20), the n = 3 averaging
filter, fixed friction compensation) on the first 1 s segment of the CPT (the 0 -> 90 deg rise,
where the torques and velocities are largest) at 250, 1000 and 2500 Hz. The paper expects
"performance to degrade gracefully with decreasing sample rate (up to a point)".
"""

import json

import pytest

from robust_drake.experiments import jaritz_spong as js

RATES = (2500.0, 1000.0, 250.0)  # falling


@pytest.fixture(scope="module")
def sweep():
    rows = js.sweep_rate(("sp1", "sp2", "zc"), RATES, workers=1, progress=False, duration=1.0)
    return {(r["controller"], r["rate"]): r for r in rows}


def _series(sweep, c, key="error_task"):
    return {rate: round(sweep[(c, rate)][key], 6) for rate in RATES}


def test_loop_stays_bounded_at_1000_hz_and_above(sweep):
    for (c, rate), r in sweep.items():
        assert "error" not in r, r
        if rate >= 1000:
            assert not r["diverged"], (c, rate)
            assert r["maxerr_task"] < 3e-3, f"{c} at {rate:g} Hz: maxerr_task {r['maxerr_task']:.5f} m"


def test_error_does_not_improve_as_the_rate_falls(sweep):
    """Between neighbouring rates the task-space error may stay flat (the simulated arm has no
    unmodelled dynamics for a fast loop to fight) but must not drop by more than 3 %."""
    for c in ("sp1", "sp2", "zc"):
        errs = _series(sweep, c)
        for hi, lo in zip(RATES, RATES[1:]):
            assert errs[lo] >= 0.97 * errs[hi], f"{c}: error improved from {hi:g} to {lo:g} Hz: {errs}"


def test_model_based_laws_degrade_at_250_hz(sweep):
    """At 250 Hz the sampling (and the 12 ms averaging window) costs SP1 and SP2 accuracy."""
    for c in ("sp1", "sp2"):
        errs = _series(sweep, c)
        assert errs[250.0] > 1.2 * errs[2500.0], f"{c}: {errs}"


def test_sweep_rate_cli_json(capsys):
    from robust_drake.cli import main

    status = main(["sweep-rate", "--controllers", "sp1", "--rates", "1000,2500", "--duration", "0.2",
                   "--workers", "1", "--json"])
    assert status == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["controller"], r["rate"]) for r in rows] == [("sp1", 1000.0), ("sp1", 2500.0)]
    for r in rows:
        assert r["error_task"] > 0 and r["chattering"] > 0 and r["diverged"] is False


def test_sweep_rate_rejects_bad_rates(capsys):
    from robust_drake.cli import main

    assert main(["sweep-rate", "--rates", "1000,-5"]) == 2
    assert "positive" in capsys.readouterr().err
