"""Messages of the repair report (issue 21 items 8 and 9): the poor-excitation warning once and
short, still rows named per joint, the verdict naming what ran, grid-edge choices flagged, the
delay's resolution stated."""


import numpy as np

from robust_drake.identification.conditioning import STICK_SPEED
from robust_drake.model_repair.pipeline import RepairOptions, run_repair
from robust_drake.model_repair.report import annotate_effects, grid_edge, once
from robust_drake.synthetic.simulated import DEFAULT_ROBOT, hidden_effect_case, simulate_experiment


def test_poor_excitation_warned_once_with_one_condition_number(tmp_path):
    """serial7 with its last two joints moving 2 mrad (a few encoder counts): their parameters are
    unidentifiable; every fit of the loop warns, the report keeps one short line."""
    from robust_drake.synthetic.battery import _sim_kwargs

    kw = _sim_kwargs("serial7")
    kw["excitation"] = dict(kw["excitation"], amplitude=[0.6] * 5 + [0.002, 0.002])
    paths = []
    for s in (0, 1):
        paths.append(str(tmp_path / f"r{s}.csv"))
        simulate_experiment("serial7", [], duration=6.0, seed=s, out_csv=paths[-1], **kw)
    rep = run_repair(paths[:1], RepairOptions(robot="serial7", replay=False, plots=False, consistent=False),
                     validate_paths=paths[1:])
    poor = [w for w in rep["warnings"] if w.startswith("poor excitation")]
    assert len(poor) == 1, poor
    assert poor[0].count("condition number") == 1 and len(poor[0]) < 200, poor[0]
    assert rep["identifiability"]["unidentifiable"]  # the names are in the report, not in the line
    assert "*" not in poor[0]


def test_once_keeps_the_first_poor_excitation_warning():
    msgs = ["poor excitation: condition number 1e5 of the column-normalised regressor", "other",
            "poor excitation: condition number 3e5 of the column-normalised regressor", "other"]
    assert once(msgs) == msgs[:2]


def test_still_rows_named_per_joint(tmp_path):
    """Joint 1 moves 4 mrad against 0.02 N m Coulomb friction and sticks for long stretches; joint 0
    swings 1 rad. The share of still rows per joint follows the simulator's true velocity: at least
    the share where the true |qd| < STICK_SPEED sustained, and small on the swinging joint."""
    paths, true_still = [], None
    for s in (0, 1):
        paths.append(str(tmp_path / f"r{s}.csv"))
        _, truth = simulate_experiment(DEFAULT_ROBOT, [], duration=8.0, seed=s, coulomb=(0.02, 0.01),
                                       excitation=dict(amplitude=(1.0, 0.004)), out_csv=paths[-1],
                                       return_result=True)
        true_still = np.mean(np.abs(truth["qd"]) < STICK_SPEED, axis=0)
    rep = run_repair(paths[:1], RepairOptions(robot=DEFAULT_ROBOT, replay=False, plots=False),
                     validate_paths=paths[1:], out_dir=str(tmp_path / "out"))
    f = rep["final"]
    assert f["stuck_share"][0] < 0.05 and f["stuck_share"][1] > 0.2, f["stuck_share"]
    assert f["stuck_share"][1] >= 0.5 * true_still[1], (f["stuck_share"], true_still)
    # the RMS over all rows is the rows' shares' mix of the two (each row counted once)
    for j in range(2):
        sh, m, st = f["stuck_share"][j], f["rms_validate_moving"][j], f["rms_validate_stuck"][j]
        mix = np.sqrt(sh * (st if sh > 0 else 0.0) ** 2 + (1 - sh) * m ** 2)
        assert np.isclose(mix, f["rms_validate"][j], rtol=1e-9)
    md = open(tmp_path / "out" / "report.md").read()
    assert md.count("of the rows still)") == 2


def test_no_replay_verdict_and_validation_wording(tmp_path):
    fit, val, truth = hidden_effect_case("torque_offset", seed=0, out_dir=str(tmp_path), duration=8.0)
    rep = run_repair([fit], RepairOptions(robot=truth["robot"], replay=False, plots=False), validate_paths=[val],
                     out_dir=str(tmp_path / "out"))
    assert "replay is not worse" not in rep["verdict_reason"]
    if rep["verdict"] == "repaired":
        assert "no replay ran" in rep["verdict_reason"]
    if rep["estimator"].get("hausman", {}).get("significant"):  # IV chosen without its replay check: said
        assert "Hausman test alone" in rep["estimator"]["decided_by"]
    md = open(tmp_path / "out" / "report.md").read()
    assert f"validation samples: {rep['samples_validate']} (from 1 validation file)" in md


def test_grid_edge_choice_flagged():
    assert grid_edge("smooth_coulomb", {"coulomb": 0.1, "transition_velocity": 1.0}) == [
        "transition_velocity = 1 at the edge of its grid [0.1, 1]"]
    assert grid_edge("smooth_coulomb", {"coulomb": 0.1, "transition_velocity": 0.3}) == []
    assert grid_edge("torque_offset", {"offset": 0.05}) == []  # no grid
    rows = [{"kind": "smooth_coulomb", "parameters": {"transition_velocity": 1.0}, "plausibility": "low-velocity"}]
    annotate_effects(rows, 0.003)
    assert rows[0]["plausibility"].startswith("AT THE EDGE OF ITS GRID")


def test_delay_resolution_stated():
    """4.6 ms at a 3.0 ms sample period: 1.5 periods, said with the period."""
    rows = [{"kind": "time_delay", "parameters": {"delay": 0.0046}, "plausibility": "delay"}]
    annotate_effects(rows, 0.003)
    assert np.isclose(rows[0]["delay_samples"], 0.0046 / 0.003)
    assert "1.5 sample periods" in rows[0]["plausibility"] and "3 ms" in rows[0]["plausibility"]
