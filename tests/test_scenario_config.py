"""Scenario.to_config: derived from the fields of Scenario and ClosedLoopConfig, so every
ClosedLoopConfig field is reachable from a scenario (directly or through ``extra``) with the
value the scenario gave, and a field added to either dataclass needs no second edit."""

from __future__ import annotations

import dataclasses
import math

import pytest

from robust_drake.diagram import ClosedLoopConfig
from robust_drake.errors import RobustDrakeError
from robust_drake.scenario import Scenario


def _feedforward(q_meas, v_hat):
    return [0.0, 0.0]


#: A plain-data value, different from the default, for every ClosedLoopConfig field.
SAMPLE = {
    "robot": "imi_scara", "load": "none", "controller": "pd", "controller_params": {"K": [3.0, 2.0]},
    "trajectory": "sine", "trajectory_params": {"amplitude": 0.2}, "rate": 1000, "observer": "euler",
    "observer_params": {"alpha": 0.5}, "plant_friction": {"coulomb": [0.3, 0.2], "viscous": [0.01, 0.02]},
    "friction_compensation": True, "compensation_params": {"k_hat": [0.1, 0.2]},
    "encoder_resolution": 1e-4, "torque_limit": [5.0, 4.0], "duration": 0.25, "metrics_skip": 0.05,
    "metrics_dt": None, "true_theta": [1, 0.1, 0.05], "initial_q": [0.1, -0.2],
    "effects": [["stribeck", {"joint": 0}]],
    "plant_setup": [["robust_drake.montecarlo:set_imi_theta", {"theta": [4.69, -0.4, 0.65, -0.09]}]],
    "feedforward": [_feedforward], "divergence_error": 2.5,
    "flexibility": {"J_m": [0.01, 0.01], "k": [1e4, 1e4]},
    "model": "out/repair/report.json", "plant_model": "out/repair/model.json",
    "compensation": [_feedforward],
}


def test_sample_covers_every_config_field():
    """A new ClosedLoopConfig field must be added here, so the next test covers it."""
    assert set(SAMPLE) == {f.name for f in dataclasses.fields(ClosedLoopConfig)}


def test_every_config_field_reaches_the_config():
    scenario_fields = {f.name for f in dataclasses.fields(Scenario)}
    direct = {k: v for k, v in SAMPLE.items() if k in scenario_fields}
    extra = {k: v for k, v in SAMPLE.items() if k not in scenario_fields}
    c = Scenario(**direct, extra=extra).to_config()
    for name, value in SAMPLE.items():
        got = getattr(c, name)
        if name == "effects":
            assert got == [("stribeck", {"joint": 0})]
        elif name == "plant_setup":
            assert len(got) == 1 and got[0].keywords == {"theta": value[0][1]["theta"]}
            assert got[0].func.__name__ == "set_imi_theta"
        elif name in ("rate", "true_theta"):
            assert got == pytest.approx(value) and all(isinstance(x, float) for x in
                                                       (got if isinstance(got, list) else [got]))
        else:
            assert got == value, name
    # every field differs from its default, so none of them was left to the default
    defaults = ClosedLoopConfig()
    assert all(getattr(c, k) != getattr(defaults, k) for k in SAMPLE if k != "load")


def test_friction_off_and_extra_plant_friction():
    assert Scenario(friction=False).to_config().plant_friction is None
    pf = {"coulomb": [0.5, 0.5], "viscous": [0.0, 0.0]}
    assert Scenario(friction=False, extra={"plant_friction": pf}).to_config().plant_friction == pf


@pytest.mark.parametrize("key", ["controller", "rate", "seed", "no_such_option"])
def test_extra_cannot_shadow_a_scenario_field_or_invent_one(key):
    with pytest.raises(RobustDrakeError, match="not a ClosedLoopConfig option"):
        Scenario(extra={key: 1}).to_config()


def test_new_fields_need_no_second_edit(monkeypatch):
    """A field added to ClosedLoopConfig is settable through ``extra``; one added to both
    dataclasses is copied directly; a config that grows a seed receives the scenario's."""
    import robust_drake.diagram as diagram

    @dataclasses.dataclass
    class GrownConfig(ClosedLoopConfig):
        new_option: float = 0.0
        seed: int = -1

    @dataclasses.dataclass
    class GrownScenario(Scenario):
        metrics_skip: float = 0.0

    monkeypatch.setattr(diagram, "ClosedLoopConfig", GrownConfig)
    c = GrownScenario(metrics_skip=0.125, seed=7, extra={"new_option": 2.5}).to_config()
    assert isinstance(c, GrownConfig)
    assert (c.new_option, c.metrics_skip, c.seed) == (2.5, 0.125, 7)
    assert math.isclose(c.rate, 2500.0)
