"""System test of the main job's second half: a hidden effect found in data, the model
repaired, and the repaired model making SP1 track better on the true arm."""

import pytest

from robust_drake.experiments.repair_control import TRUE_EFFECT, run


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    out = tmp_path_factory.mktemp("repair_control")
    return run(str(out), duration=12.0, track_duration=2.0, trajectories=("cpt",), progress=lambda m: None)


def test_hidden_cogging_is_found(loop):
    kind, joint, truth = TRUE_EFFECT
    found = [e for e in loop["repair"]["effects"] if e["kind"] == kind and e["joint"] == joint]
    assert found, f"effects found: {[(e['kind'], e['joint']) for e in loop['repair']['effects']]}"
    amp = found[0]["parameters"]["amplitude"]
    assert abs(amp - truth["amplitude"]) < 0.3 * truth["amplitude"], amp


def test_repair_lowers_validation_error(loop):
    rep = loop["repair"]
    for j in range(2):
        assert rep["final"]["rms_validate"][j] < rep["baseline"]["rms_validate"][j]
    assert rep["final"]["rms_validate"][1] < 0.8 * rep["baseline"]["rms_validate"][1]


def test_repaired_model_improves_sp1_tracking(loop):
    rows = {r["model"]: r for r in loop["tracking"]}
    b, f = rows["baseline"], rows["repaired"]
    assert f["error_task"] < 0.9 * b["error_task"], (b["error_task"], f["error_task"])
    assert f["maxerr_task"] < b["maxerr_task"]
