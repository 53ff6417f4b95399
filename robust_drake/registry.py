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
    "file": "robust_drake.trajectories:make_file",  # trajectory CSV (path=...); a name ending in .csv is one too
}

PLANT_EFFECTS: dict[str, str] = {
    "coulomb_viscous": "robust_drake.systems.friction:make_coulomb_viscous",
    "sigmoid_friction": "robust_drake.systems.sigmoid_friction:make_sigmoid_friction",
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


# --- user systems in the loop: a registry name, a LeafSystem instance or a factory ----------

#: Ports a block of each kind must have: name -> size as a multiple of n (number of joints).
#: ``optional_inputs`` are connected when present (observers may read the true ``state`` (2n)
#: or the applied torque ``tau`` (n)); any other input port would be left unconnected.
PORT_CONTRACT: dict[str, dict[str, dict[str, int]]] = {
    "controller": {"inputs": {"x_d": 3, "q": 1, "v": 1, "v_error": 1}, "outputs": {"u": 1},
                   "optional_inputs": {}},
    "observer": {"inputs": {"q": 1, "x_d": 3}, "outputs": {"v": 1, "v_error": 1},
                 "optional_inputs": {"state": 2, "tau": 1}},
}

# instances already put into a closed loop (Drake lets a System be built into one Diagram only)
_USED_INSTANCES = None


def block_label(spec) -> str:
    """A printable name for a block given as a registry name, an instance or a factory."""
    if isinstance(spec, str):
        return spec
    from pydrake.systems.framework import System

    if isinstance(spec, System):
        return f"custom:{type(spec).__name__}"
    return f"custom:{getattr(spec, '__name__', type(spec).__name__)}"


def is_block_spec(spec) -> bool:
    """True for what ``ClosedLoopConfig.controller``/``observer`` accept: a non-empty name, a
    pydrake ``System`` instance, or a callable factory ``f(ctx, **params) -> System``."""
    from pydrake.systems.framework import System

    return (isinstance(spec, str) and bool(spec)) or isinstance(spec, System) or callable(spec)


def check_ports(kind: str, block, n: int) -> None:
    """Raise :class:`RobustDrakeError` naming the first missing, mis-sized or unexpected port of
    ``block`` against :data:`PORT_CONTRACT` [kind] for an arm with ``n`` joints."""
    contract = PORT_CONTRACT[kind]
    label = block_label(block)
    for direction, ports in (("input", contract["inputs"]), ("output", contract["outputs"])):
        has = block.HasInputPort if direction == "input" else block.HasOutputPort
        get = block.GetInputPort if direction == "input" else block.GetOutputPort
        for name, mult in ports.items():
            if not has(name):
                raise RobustDrakeError(
                    f"{kind} {label} has no {direction} port {name!r} (size {mult * n}); a {kind} needs "
                    f"inputs {_port_list(contract['inputs'], n)} and outputs {_port_list(contract['outputs'], n)}")
            port = get(name)
            if port.get_data_type().name != "kVectorValued" or port.size() != mult * n:
                raise RobustDrakeError(
                    f"{kind} {label}: {direction} port {name!r} must be a vector of size {mult * n} "
                    f"for this {n}-joint arm (got size {port.size()})")
    allowed = set(contract["inputs"]) | set(contract["optional_inputs"])
    for i in range(block.num_input_ports()):
        port = block.get_input_port(i)
        name = port.get_name()
        if name not in allowed:
            raise RobustDrakeError(
                f"{kind} {label} has input port {name!r} that the closed loop cannot connect; "
                f"allowed inputs: {', '.join(sorted(allowed))}")
        mult = contract["optional_inputs"].get(name)
        if mult is not None and port.size() != mult * n:
            raise RobustDrakeError(
                f"{kind} {label}: input port {name!r} must be a vector of size {mult * n} (got size {port.size()})")


def _port_list(ports: dict, n: int) -> str:
    return ", ".join(f"{k} ({m * n})" for k, m in ports.items())


def make_block(kind: str, spec, ctx: BuildContext, params: dict):
    """The block ``spec`` stands for, with its ports checked for controllers and observers.

    ``spec`` is a registry name (``resolve(kind, spec)(ctx, **params)``), a pydrake ``System``
    instance (used as is; ``params`` must be empty; one closed loop per instance), or a
    callable factory ``f(ctx, **params) -> System``. A wrong parameter name or value is a
    one-line user error naming the block.
    """
    global _USED_INSTANCES
    from pydrake.systems.framework import System

    params = dict(params)
    if isinstance(spec, System):
        if params:
            raise RobustDrakeError(
                f"{kind} {block_label(spec)} is a System instance; {kind}_params apply to names and factories only")
        if _USED_INSTANCES is None:
            import weakref

            _USED_INSTANCES = weakref.WeakSet()
        if spec in _USED_INSTANCES:
            raise RobustDrakeError(
                f"{kind} {block_label(spec)} is already part of a closed loop (a Drake System can be in one "
                f"diagram only); pass a factory f(ctx) -> System to build the loop more than once")
        block = spec
    else:
        factory = resolve(kind, spec) if isinstance(spec, str) else spec
        if not callable(factory):
            raise RobustDrakeError(
                f"{kind} must be a registry name, a pydrake System or a factory f(ctx) -> System (got {spec!r})")
        try:
            block = factory(ctx, **params)
        except RobustDrakeError:
            raise  # already a one-line user error naming the block
        except (TypeError, ValueError) as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise RobustDrakeError(f"{kind} {block_label(spec)!r} with parameters {params!r}: {msg}") from None
        if not isinstance(block, System):
            raise RobustDrakeError(
                f"{kind} factory {block_label(spec)} returned {type(block).__name__}, not a pydrake System")
    if kind in PORT_CONTRACT:
        check_ports(kind, block, ctx.n)
    if isinstance(spec, System):
        _USED_INSTANCES.add(spec)
    return block
