"""The registry of effect kinds: :data:`EFFECTS` (kind name -> class), the kinds offered only
after a diagnostic, and the constructors :func:`make_effect` and :func:`all_candidates`.
"""

from __future__ import annotations

from robust_drake.effects.base import Effect
from robust_drake.effects.diagnosed import DeadZone, FrictionDrift, PeriodicDisturbanceEffect
from robust_drake.effects.friction import (AsymmetricCoulomb, LoadDependentFriction, PreslidingFriction,
                                           SmoothCoulomb, Stribeck)
from robust_drake.effects.plant import Payload, RotorInertia
from robust_drake.effects.position import ConfigurationDependent, PositionDependent, Spring
from robust_drake.effects.sensor import TimeDelay, TorqueOffset, TorqueScale
from robust_drake.errors import RobustDrakeError


EFFECTS: dict[str, type[Effect]] = {
    cls.kind: cls for cls in (Stribeck, SmoothCoulomb, AsymmetricCoulomb, LoadDependentFriction,
                              PositionDependent, TorqueOffset, TorqueScale, RotorInertia, Spring,
                              TimeDelay, Payload, PreslidingFriction,
                              PeriodicDisturbanceEffect, DeadZone, FrictionDrift, ConfigurationDependent)
}


#: kinds offered only where a residual diagnostic found their structure (``candidates`` needs
#: ``diagnostics=``); they have no entry in ``simulated.HIDDEN_CASES`` but cases in
#: ``simulated_cases.OUTSIDE_CASES`` (``configuration_dependent``: the PUMA cable of
#: tests/test_configuration_dependent.py, offered by ``residual.configuration_dependence``)
DIAGNOSTIC_KINDS = ("periodic_disturbance", "dead_zone", "friction_drift", "configuration_dependent")


def make_effect(kind: str, joint: int | None = None, **shape) -> Effect:
    """An effect instance by kind name (RobustDrakeError listing the kinds if unknown); ``joint``
    is the 0-based joint index (``make_effect("spring", 1).name == "spring[2]"``)."""
    try:
        cls = EFFECTS[kind]
    except KeyError:
        raise RobustDrakeError(f"unknown effect kind {kind!r}; known: {', '.join(EFFECTS)}") from None
    return cls(joint=joint, **shape)


def all_candidates(n_joints: int, kinds=None, **context) -> list[Effect]:
    """Every candidate instance of the given kinds (default all) for an n-joint arm."""
    out = []
    for k in kinds or EFFECTS:
        out.extend(EFFECTS[k].candidates(n_joints, **context))
    return out
