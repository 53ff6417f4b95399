"""The epsilon search of JS section 9 / table 1: the vibration measure and the search rule on known
signals, then one measured closed-loop fact (ZC chatters at a small epsilon, not at table 1's)."""

import json

import numpy as np
import pytest

from robust_drake.experiments.epsilon_search import smallest_free, vibration_fraction


def test_vibration_fraction_is_the_power_share_above_the_cut():
    """Parseval: a 2 Hz sine of amplitude A plus a 300 Hz sine of amplitude B has B^2 / (A^2 + B^2) of
    its power above 50 Hz; a smooth motion alone has almost none."""
    rate = 2500.0
    t = np.arange(0.0, 2.1, 1 / rate)
    A, B = 3.0, 0.5
    tau = np.column_stack([A * np.sin(2 * np.pi * 2 * t) + B * np.sin(2 * np.pi * 300 * t) + 7.0,
                           A * np.sin(2 * np.pi * 2 * t)])
    V = vibration_fraction(tau, rate)
    assert V[0] == pytest.approx(B ** 2 / (A ** 2 + B ** 2), rel=0.02)
    assert V[1] < 1e-4
    assert vibration_fraction(tau, rate, f_cut=400.0)[0] < 1e-4      # the 300 Hz line is below this cut


def test_smallest_free_needs_every_larger_epsilon_free():
    rows = [{"factor": f, "vibration": [v], "diverged": False}
            for f, v in ((0.25, 0.001), (0.5, 0.2), (1.0, 0.005), (2.0, 0.002))]
    assert smallest_free(rows, 0.01)["factor"] == 1.0                 # 0.25 is free but 0.5 vibrates
    rows[-1]["diverged"] = True
    assert smallest_free(rows, 0.01) is None


def test_zc_chatters_at_a_small_epsilon_and_not_at_table_1():
    """JS section 5: 'for any choice of gains and sampling period the control will chatter for small
    epsilon'. Measured (full 2 s CPT, rigid): ZC's torque has 62-93 % of its power above 50 Hz at epsilon
    = 25/64, and < 0.1 % at table 1's 25."""
    from robust_drake.experiments import jaritz_spong as js
    from robust_drake.experiments.epsilon_search import run_vibration

    out = {}
    for f in (1 / 64, 1.0):
        s = js.run_spec(2, "zc", controller_params={"epsilon": 25.0 * f})
        s["factor"] = f
        out[f] = run_vibration(s)
    assert max(out[1 / 64]["vibration"]) > 0.3
    assert max(out[1.0]["vibration"]) < 0.01
    assert out[1 / 64]["error_task"] < out[1.0]["error_task"]         # the chatter buys accuracy (rigid arm)


def test_cli_json_and_errors(capsys):
    from robust_drake.cli import main

    assert main(["epsilon-search", "--controllers", "zc", "--factors", "0.0156,1", "--duration", "0.4",
                 "--workers", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    (res,) = out["results"]
    assert res["published"] == {"epsilon": 25.0} and len(out["runs"]) == 2
    assert [r["factor"] for r in out["runs"]] == [0.0156, 1.0]
    assert main(["epsilon-search", "--controllers", "sp9"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
