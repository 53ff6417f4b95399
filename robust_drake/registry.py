"""Name -> factory tables for the pieces the closed-loop builder can pick by name.

Entries are lazy ``"module:function"`` strings so that importing the registry does
not import every controller. To add a controller, observer, trajectory or plant
effect, write its module and add one line here.

Factory signatures:

- controller:  ``factory(ctx: BuildContext, **params) -> LeafSystem`` with ports
  ``x_d, q, v, v_error -> u`` (see :mod:`robust_drake.systems.controllers.base`);
- observer:    ``factory(ctx, **params) -> LeafSystem`` with ports ``q, x_d -> v, v_error``;
- trajectory:  ``factory(arm: ArmSpec, **params) -> Reference``;
- plant effect: ``factory(ctx, **params) -> LeafSystem`` with port ``state -> generalized_force``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Callable

from robust_drake.errors import RobustDrakeError

CONTROLLERS: dict[str, str] = {
    "pd": "robust_drake.systems.controllers.spong:make_pd",
    "sp1": "robust_drake.systems.controllers.spong:make_sp1",
    "sp2": "robust_drake.systems.controllers.spong:make_sp2",
    "bascetta_a": "robust_drake.systems.controllers.bascetta_rocco:make_bascetta_a",
    "bascetta_b": "robust_drake.systems.controllers.bascetta_rocco:make_bascetta_b",
    "zc": "robust_drake.systems.controllers.zenieh_corless:make_zc",
    "lg": "robust_drake.systems.controllers.liu_goldenberg:make_lg",
    "lgplus": "robust_drake.systems.controllers.liu_goldenberg:make_lgplus",
    "sp1_robust_friction": "robust_drake.systems.controllers.spong_friction:make_sp1_robust_friction",
    "sp2_robust_friction": "robust_drake.systems.controllers.spong_friction:make_sp2_robust_friction",
    "zc_robust_friction": "robust_drake.systems.controllers.spong_friction:make_zc_robust_friction",
    "lg_robust_friction": "robust_drake.systems.controllers.spong_friction:make_lg_robust_friction",
    "lgplus_robust_friction": "robust_drake.systems.controllers.spong_friction:make_lgplus_robust_friction",
    "calafiore": "robust_drake.systems.controllers.calafiore_indri:make_calafiore",
    "calafiore_nominal": "robust_drake.systems.controllers.calafiore_indri:make_calafiore_nominal",
}

OBSERVERS: dict[str, str] = {
    "averaging": "robust_drake.systems.observers:make_averaging",
    "exact": "robust_drake.systems.observers:make_exact",
    "euler": "robust_drake.systems.estimators:make_euler",
    "filtered": "robust_drake.systems.estimators:make_filtered",
    "averaging67": "robust_drake.systems.estimators:make_averaging67",
    "averaging65": "robust_drake.systems.estimators:make_averaging65",
    "kalman": "robust_drake.systems.kalman_observer:make_kalman",
    "nonlinear": "robust_drake.systems.nonlinear_observer:make_nonlinear",
}

TRAJECTORIES: dict[str, str] = {
    "cpt": "robust_drake.trajectories:make_cpt",
    "circle": "robust_drake.trajectories:make_circle",
    "refmodel": "robust_drake.trajectories:make_refmodel",
    "sine": "robust_drake.trajectories:make_sine",
    "step": "robust_drake.trajectories:make_step",
    "line": "robust_drake.trajectories:make_line",
}

PLANT_EFFECTS: dict[str, str] = {
    "coulomb_viscous": "robust_drake.systems.friction:make_coulomb_viscous",
}

_TABLES = {
    "controller": CONTROLLERS,
    "observer": OBSERVERS,
    "trajectory": TRAJECTORIES,
    "plant_effect": PLANT_EFFECTS,
}


@dataclass
class BuildContext:
    """What a factory may need to know about the loop it is built into."""

    robot: str
    arm: Any  # robust_drake.models.ArmSpec
    load: str
    n: int
    period: float  # controller/observer sample period [s]
    config: Any  # robust_drake.diagram.ClosedLoopConfig


def names(kind: str) -> list[str]:
    """Known names for ``kind`` in {'controller', 'observer', 'trajectory', 'plant_effect'}."""
    return sorted(_TABLES[kind])


def resolve(kind: str, name: str) -> Callable:
    """Return the factory registered as ``name`` in table ``kind``.

    Raises :class:`RobustDrakeError` naming the known entries when ``name`` is unknown.
    """
    table = _TABLES.get(kind)
    if table is None:
        raise RobustDrakeError(f"unknown registry table {kind!r}; known: {sorted(_TABLES)}")
    target = table.get(name)
    if target is None:
        raise RobustDrakeError(f"unknown {kind} {name!r}; known: {', '.join(sorted(table))}")
    module_name, _, func_name = target.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, func_name)
