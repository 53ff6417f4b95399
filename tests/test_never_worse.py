"""Never worse (issue 13): a repaired model may not validate worse than the baseline on any joint.

Simulated arms (the default 2-DOF URDF) with a torque outside the effect library: a disturbance
periodic in *time* (no library column depends on t). Without the guard (main at f12ee0c,
measured 2026-12-01) the selection claimed a time_delay on joint 1 for the 3 Hz disturbance
(joint 0 validated +3.6 % worse) and two position_dependent cogging terms for the 0.4 Hz one
(joints +13 % / +26 % worse, replay worse). The guard must drop them, say why, and end with
no joint worse than the baseline beyond the comparison's own spread (issue 21: paired block tests
with the tolerance as non-inferiority margin).
"""

import numpy as np
import pytest

from robust_drake.synthetic.simulated import DEFAULT_ROBOT, PeriodicDisturbance, simulate_experiment

CASES = {"3Hz_joint1": ((0.0, 0.1), 3.0), "0.4Hz_both": ((0.06, 0.06), 0.4)}


@pytest.fixture(scope="module", params=sorted(CASES))
def repaired(request, tmp_path_factory):
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair

    amp, f = CASES[request.param]
    out = tmp_path_factory.mktemp("never_worse")
    paths = []
    for role, seed in (("fit", 0), ("validate", 1)):
        p = str(out / f"{role}.csv")
        simulate_experiment(DEFAULT_ROBOT, [], duration=12.0, seed=seed, out_csv=p, coulomb=(0.02, 0.01),
                            extra_blocks=(lambda n: PeriodicDisturbance(n, amp, f, 0.3),))
        paths.append(p)
    rep = run_repair([paths[0]], RepairOptions(robot=DEFAULT_ROBOT, plots=False), validate_paths=[paths[1]],
                     out_dir=str(out / "report"))
    return rep, (out / "report" / "report.md").read_text()


def test_no_joint_validates_worse_than_the_baseline(repaired):
    """Worse = worse beyond the comparison's own spread (issue 21: paired block test, Holm over
    joints, the tolerance as non-inferiority margin). Before issue 21 this asserted the replay's
    point RMS within 1 % of the baseline's; on the 0.4 Hz case the kept periodic_disturbance[1]
    (0.413 Hz for the simulator's 0.4 Hz, validation joint 1 -68 %) replays joint 0
    +32.5 % [-33.2, +75.1] (95 %, 20 windows): not a change the 20 windows can tell from none."""
    rep, _ = repaired
    nw = rep["never_worse"]
    tol = nw["tolerance"]
    assert 0 < tol <= 0.02 and nw["level"] == 0.95
    base, final = np.array(rep["baseline"]["rms_validate"]), np.array(rep["final"]["rms_validate"])
    for tests, ref, new in ((rep["final"]["validate_change"], base, final),
                            (rep["replay"]["after"]["tests"], rep["replay"]["before"]["rms_q"],
                             rep["replay"]["after"]["rms_q"])):
        assert len(tests) == len(base)
        for j, t in enumerate(tests):
            # not worse = the data do not show the RMS above the reference's by more than the margin
            assert not t["worse"], (j, t)
            assert np.sign(t["estimate"]) == np.sign(new[j] / ref[j] - 1) or abs(new[j] / ref[j] - 1) < 0.01


def test_what_was_tried_is_reported_with_the_reason(repaired):
    rep, md = repaired
    # what the selection accepted (since issue 21's calibrated selection the 0.4 Hz case accepts
    # nothing: its cogging candidates fail the confirmation test, so the guard has nothing to drop)
    accepted = [s["label"] for s in rep["selection"]["steps"] if s["accepted"]]
    # ... and every accepted effect the final model does not hold is listed as dropped, with why
    dropped = {d["label"]: d for d in rep["rejected_effects"]}
    kept = {e["label"] for e in rep["effects"] if e["source"] == "residual"}
    # (the 3 Hz case: the periodic diagnostic offers periodic_disturbance on joint 1, which is
    # kept; nothing to drop there)
    assert set(accepted) - kept <= set(dropped)
    for d in dropped.values():
        assert d["kept"] is False and "worse" in d["reason"]
    assert rep["verdict"] == ("repaired" if kept else "no_improvement")
    assert f"Verdict: {rep['verdict']}" in md
    assert ("dropped by the never-worse rule" in md) == bool(dropped)
    for label in dropped:
        assert label in md


def test_markdown_and_json_agree_on_the_estimator(repaired):
    rep, md = repaired
    est = rep["estimator"]
    if est.get("hausman"):
        sig = est["hausman"]["significant"]
        md = md.split("## Errors in variables")[1].split("\n## ")[0]  # the estimator's section
        assert ("**significant**" in md) == sig and ("**not significant**" in md) == (not sig)
        used = "instrumental variables" if est["method"] == "instrumental_variables" else "least squares"
        assert f"Estimator used: {used}" in md
