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

from robust_drake.errors import RobustDrakeError, did_you_mean  # noqa: F401 - re-exported

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


# --- what a person types and reads: paper names, aliases, parameters with units ------------------

#: The names the papers' tables print (figures and tables use them; :func:`canonical` accepts them).
PAPER_NAMES: dict[str, str] = {
    "pd": "PD", "sp1": "SP1", "sp2": "SP2", "zc": "ZC", "lg": "LG", "lgplus": "LG+",
    "bascetta_a": "BR Case A", "bascetta_b": "BR Case B",
    "sp1_robust_friction": "SP1 + robust friction", "sp2_robust_friction": "SP2 + robust friction",
    "zc_robust_friction": "ZC + robust friction", "lg_robust_friction": "LG + robust friction",
    "lgplus_robust_friction": "LG+ + robust friction",
    "calafiore": "CI robust", "calafiore_nominal": "CI nominal",
    "cpt": "CPT", "circle": "circle", "refmodel": "reference model", "sine": "sine", "step": "step",
    "line": "line",
}

#: Other spellings accepted for a registry name (compared case-insensitively).
ALIASES: dict[str, dict[str, str]] = {
    "controller": {"lg+": "lgplus", "lg_plus": "lgplus", "br_a": "bascetta_a", "br_b": "bascetta_b",
                   "case_a": "bascetta_a", "case_b": "bascetta_b", "ci": "calafiore",
                   "ci_nominal": "calafiore_nominal"},
    "observer": {}, "trajectory": {}, "plant_effect": {},
}

_GAINS = {"K": ("N m s/rad", "gain on r = e_dot + Lambda e, per joint (JS eq. 11)"),
          "Lambda": ("1/s", "sliding-surface slope per joint (JS eq. 11)")}
_BOX = {"rel_bound": ("-", "relative half-width of the parameter box around theta0 (any URDF arm)"),
        "abs_bound": ("parameter units", "absolute half-width of that box")}
_FRICTION = {"k_hat": ("N m", "nominal Coulomb level per joint (JS eq. 90)"),
             "rho_k": ("N m", "bound on its error (JS section 11)")}

#: kind -> name -> {"summary", "paper", "params": {name: (unit, description)}}. For trajectories,
#: observers and plant effects the accepted names are the factory's signature (checked by the
#: tests); for controllers the documented ones (factories take ``**params``).
CATALOG: dict[str, dict[str, dict]] = {
    "controller": {
        "pd": {"summary": "PD on the sliding variable, the gains of SP1/SP2", "paper": "JS section 8",
               "params": dict(_GAINS)},
        "sp1": {"summary": "Spong's robust law, one bound rho on ||theta - theta0||", "paper": "JS eqs. 9-12, 18",
                "params": {**_GAINS, "theta0": ("parameter units", "nominal parameters (JS eq. 16)"),
                           "rho": ("parameter units", "bound on ||theta - theta0|| (JS eq. 17)"),
                           "epsilon": ("-", "boundary-layer width of the robust term, in the units of ||Y^T r|| (JS eq. 18)"),
                           **_BOX, "regressor": ("callable", "Y(q, qd, v, a) of your own, with theta0/rho")}},
        "sp2": {"summary": "Spong's robust law, one bound per parameter", "paper": "JS eqs. 9-12 (SP2)",
                "params": {**_GAINS, "theta0": ("parameter units", "nominal parameters (JS eq. 16)"),
                           "rho": ("parameter units", "per-parameter bounds (JS table 10)"),
                           "epsilon": ("-", "boundary-layer width, in the units of ||Y^T r|| (JS table 1)"),
                           **_BOX, "regressor": ("callable", "Y(q, qd, v, a) of your own, with theta0/rho")}},
        "zc": {"summary": "Zenieh & Corless robust law", "paper": "JS eqs. 21-28",
               "params": {**_GAINS, "beta1": ("-", "bound coefficient (JS eq. 23)"),
                          "beta2": ("-", "bound coefficient (JS eq. 23)"),
                          "epsilon": ("-", "boundary layer (JS table 1: 25, circle 45)"), **_BOX}},
        "lg": {"summary": "Liu & Goldenberg, nominal = the unloaded arm", "paper": "JS eqs. 29-35",
               "params": {**_GAINS, "theta_nom": ("kg m^2", "nominal theta of JS eq. 14"),
                          "width": ("kg m^2", "interval width per parameter"),
                          "eps_M": ("-", "inertia-term boundary layer"), "eps_C": ("-", "Coriolis-term boundary layer")}},
        "lgplus": {"summary": "LG+, Liu & Goldenberg with the nominal at the interval centre",
                   "paper": "JS section 5",
                   "params": {**_GAINS, "theta_nom": ("kg m^2", "nominal theta of JS eq. 14"),
                              "width": ("kg m^2", "interval half-width per parameter"),
                              "eps_M": ("-", "inertia-term boundary layer"),
                              "eps_C": ("-", "Coriolis-term boundary layer")}},
        "bascetta_a": {"summary": "robust inverse dynamics, classical Lyapunov design", "paper": "BR eqs. 12-13",
                       "params": {"K_P": ("1/s^2", "proportional gain"), "K_D": ("1/s", "derivative gain"),
                                  "perturbation": ("-", "relative mass error of the controller model"),
                                  "boundary": ("rad", "boundary layer of the robust term"),
                                  "region": ("-", "'trajectory' or 'global': where the bounds are sampled"),
                                  "tube": ("rad", "half-width of the tube around the reference"),
                                  "Q": ("-", "Lyapunov weight"), "mass_model": ("-", "diag_q0 | model"),
                                  "delta": ("-", "bound override"), "gamma": ("-", "bound override"),
                                  "beta": ("-", "rho polynomial override"), "n_time": ("-", "time samples of the bounds")}},
        "bascetta_b": {"summary": "robust inverse dynamics, Riccati design", "paper": "BR eqs. 17-20",
                       "params": {}},  # filled below: the same as Case A
        "calafiore": {"summary": "Calafiore & Indri robust law from a confidence ellipsoid",
                      "paper": "CI eqs. 6-8, 15",
                      "params": {**_GAINS, "theta0": ("parameter units", "ellipsoid centre (CI section 5.1)"),
                                 "P": ("parameter units^2", "ellipsoid shape matrix"),
                                 "E": ("parameter units", "E with E E^T = P (instead of P)"),
                                 "epsilon": ("-", "boundary layer of eq. 15"),
                                 "regressor": ("callable", "your own control regressor")}},
        "calafiore_nominal": {"summary": "Calafiore & Indri nominal law only", "paper": "CI eq. 6",
                              "params": {**_GAINS, "theta0": ("parameter units", "model parameters"),
                                         "regressor": ("callable", "your own control regressor")}},
    },
}
CATALOG["controller"]["bascetta_b"]["params"] = dict(CATALOG["controller"]["bascetta_a"]["params"])
for _base in ("sp1", "sp2", "zc", "lg", "lgplus"):
    _extra = dict(_FRICTION, **({} if _base.startswith("sp") else {"eps_F": ("N m", "friction boundary layer")}))
    CATALOG["controller"][f"{_base}_robust_friction"] = {
        "summary": f"{PAPER_NAMES[_base]} with the robust friction term", "paper": "JS section 11",
        "params": {**CATALOG["controller"][_base]["params"], **_extra}}

#: units of trajectory / observer / effect factory parameters (by parameter name)
PARAM_UNITS: dict[str, tuple[str, str]] = {
    "amplitude_deg": ("deg", "peak joint motion"), "segment": ("s", "duration of each cubic"),
    "offset": ("rad", "start posture per joint (default: inside the joint limits)"),
    "center": ("m", "circle centre (x, y)"), "radius": ("m", "circle radius"),
    "omega": ("rad/s", "angular frequency"), "duration": ("s", "length of the reference"),
    "elbow": ("-", "'up' or 'down' inverse-kinematics branch"), "amplitude": ("rad", "amplitude per joint"),
    "zeta": ("-", "damping ratio"), "t0": ("s", "step time"), "start": ("m", "start point (x, y)"),
    "end": ("m", "end point (x, y)"), "T": ("s", "motion time"), "Ta": ("s", "acceleration time"),
    "hold": ("s", "rest at the end"), "n_avg": ("-", "samples averaged (JS eq. 66)"),
    "window": ("-", "samples in the window"), "nu": ("-", "filter pole"), "normalize": ("-", "unit DC gain"),
    "python": ("-", "use the Python block instead of the C++ one"), "c": ("-", "Kalman noise ratio"),
    "theta_m": ("rad", "encoder quantum"), "L1": ("1/s", "observer gain"), "L2": ("1/s^2", "observer gain"),
    "theta": ("parameter units", "model parameters of the observer"),
    "coulomb": ("N m", "Coulomb level per joint"), "viscous": ("N m s/rad", "viscous coefficient per joint"),
    "phi1": ("N m", "sigmoid friction level"), "phi2": ("s/rad", "sigmoid slope"), "phi3": ("N m s/rad", "viscous part"),
}


def canonical(kind: str, name: str) -> str:
    """The registry name ``name`` stands for: itself, its lower-case form (``"SP1"`` -> ``"sp1"``),
    an alias (``"LG+"`` -> ``"lgplus"``) or its paper name. Raises :class:`RobustDrakeError`
    with the nearest known names ("did you mean ...") when none matches."""
    table = _TABLES.get(kind)
    if table is None:
        raise RobustDrakeError(f"unknown registry table {kind!r}; known: {sorted(_TABLES)}")
    if name in table:
        return name
    key = str(name).strip().lower().replace("-", "_").replace(" ", "_")
    if key in table:
        return key
    aliases = {**ALIASES.get(kind, {}),
               **{v.lower().replace(" ", "_"): k for k, v in PAPER_NAMES.items() if k in table}}
    if key in aliases:
        return aliases[key]
    raise RobustDrakeError(f"unknown {kind} {name!r}{did_you_mean(key, list(table) + list(ALIASES.get(kind, {})))}; "
                           f"known: {', '.join(sorted(table))}")


def canonical_or_same(kind: str, spec):
    """:func:`canonical` for a known name, anything else (an unknown name, an instance, a factory)
    unchanged, so that the builder's own error reports it in context."""
    if not isinstance(spec, str):
        return spec
    try:
        return canonical(kind, spec)
    except RobustDrakeError:
        return spec


def canonical_robot(robot):
    """A shipped robot's name in any case (``"D2R2"`` -> ``"d2r2"``); anything else unchanged."""
    if not isinstance(robot, str):
        return robot
    from robust_drake.models import ROBOTS

    if robot in ROBOTS:
        return robot
    key = robot.strip().lower()
    return key if key in ROBOTS else robot


def paper_name(name) -> str:
    """The paper's name for a registry name (``"lgplus"`` -> ``"LG+"``); other labels unchanged."""
    return PAPER_NAMES.get(str(name), str(name))


def accepted_params(kind: str, name: str) -> dict[str, tuple[str, str]]:
    """``{parameter: (unit, description)}`` a registry entry accepts: the catalog's (controllers)
    or its factory's keyword arguments (trajectories, observers, plant effects)."""
    import inspect

    name = canonical(kind, name)
    entry = CATALOG.get(kind, {}).get(name)
    if entry is not None:
        return dict(entry["params"])
    sig = inspect.signature(resolve(kind, name))
    out = {}
    for i, (p, par) in enumerate(sig.parameters.items()):
        if i == 0 or par.kind in (par.VAR_KEYWORD, par.VAR_POSITIONAL):
            continue  # arm / ctx
        out[p] = PARAM_UNITS.get(p, ("-", ""))
    return out


def param_error(kind: str, name: str, params: dict, message: str) -> str | None:
    """A one-line message for a wrong parameter *name* (``message`` is the TypeError's text, e.g.
    "make_cpt() got an unexpected keyword argument 'amp'"): the bad name, the nearest accepted
    ones and the whole accepted list with units; None when ``message`` is about something else."""
    import re

    m = re.search(r"unexpected keyword argument '([^']+)'", message)
    if m is None:
        return None
    bad = m.group(1)
    try:
        ok = accepted_params(kind, name)
    except RobustDrakeError:
        return None
    listed = ", ".join(f"{p} [{u}]" for p, (u, _) in ok.items()) or "none"
    return (f"{kind} {name!r} has no parameter {bad!r}{did_you_mean(bad, list(ok))}; "
            f"accepted: {listed} (robust-drake list {_LIST_WORD[kind]})")


_LIST_WORD = {"controller": "controllers", "observer": "observers", "trajectory": "trajectories",
              "plant_effect": "plant-effects"}


def catalog() -> dict:
    """Everything the registry offers, for ``robust-drake list`` and :func:`robust_drake.list_controllers`
    and friends: ``{"robots": [...], "controllers": [...], "observers": [...], "trajectories": [...],
    "plant_effects": [...]}``, each entry a dict with ``name``, ``paper_name``, ``summary`` and
    ``parameters`` (``[{"name", "unit", "description"}]``)."""
    out = {"robots": list_robots()}
    for kind in ("controller", "observer", "trajectory", "plant_effect"):
        rows = []
        for name in names(kind):
            entry = CATALOG.get(kind, {}).get(name, {})
            doc = ""
            if not entry:
                target = _TABLES[kind][name]
                func = getattr(importlib.import_module(target.partition(":")[0]), target.partition(":")[2])
                doc = ((func.__doc__ or "").strip().splitlines() or [""])[0]
            rows.append({"name": name, "paper_name": paper_name(name), "summary": entry.get("summary", doc),
                         "paper": entry.get("paper"),
                         "parameters": [{"name": p, "unit": u, "description": d}
                                        for p, (u, d) in accepted_params(kind, name).items()]})
        out[_LIST_WORD[kind].replace("-", "_")] = rows
    return out


def list_robots() -> list[dict]:
    """The shipped robots: ``name``, ``joints``, ``loads``, ``sample_rate`` [Hz], ``torque_limits``
    [N m], ``gravity``, ``plane`` and a one-line ``summary`` (from ``robots/<name>.yaml``)."""
    from robust_drake.description import describe
    from robust_drake.models import ROBOTS

    rows = []
    for name in sorted(ROBOTS):
        d, arm = describe(name), ROBOTS[name]
        rows.append({"name": name, "joints": arm.n, "loads": sorted(arm.loads), "sample_rate": d.sample_rate,
                     "torque_limits": None if d.torque_limits is None else list(d.torque_limits),
                     "gravity": arm.gravity, "plane": arm.plane, "summary": d.summary})
    return rows


def resolve(kind: str, name: str) -> Callable:
    """Return the factory registered as ``name`` in table ``kind`` (``name`` as :func:`canonical`
    accepts it: any case, aliases, paper names).

    Raises :class:`RobustDrakeError` naming the nearest and the known entries when ``name`` is unknown.
    """
    target = _TABLES[kind][canonical(kind, name)]  # canonical() refuses an unknown kind or name
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
        except (RobustDrakeError, TypeError, ValueError) as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            better = param_error(kind, spec, params, msg) if isinstance(spec, str) else None
            if better is not None:
                raise RobustDrakeError(better) from None
            if isinstance(exc, RobustDrakeError):
                raise  # already a one-line user error naming the block
            raise RobustDrakeError(f"{kind} {block_label(spec)!r} with parameters {params!r}: {msg}") from None
        if not isinstance(block, System):
            raise RobustDrakeError(
                f"{kind} factory {block_label(spec)} returned {type(block).__name__}, not a pydrake System")
    if kind in PORT_CONTRACT:
        check_ports(kind, block, ctx.n)
    if isinstance(spec, System):
        _USED_INSTANCES.add(spec)
    return block
