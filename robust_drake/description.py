"""Robot descriptions: the per-robot facts that are not in the URDF, one file per robot.

A description is a YAML file next to the robot's URDF: ``robust_drake/robots/<name>.yaml`` for
the shipped arms, ``<stem>.yaml`` beside a user's ``<stem>.urdf``.  :func:`describe` looks it up
by robot (a name in ``robust_drake.models.ROBOTS`` or a URDF path); a robot without a file gets
:data:`DEFAULT` (no plant friction, exact encoder, no torque limit, nothing known about the
drive).  Code asks the description, never the robot's name: the closed loop's plant defaults
(:meth:`RobotDescription.closed_loop_defaults`, each overridable in ``ClosedLoopConfig``), which
closed-form regressor and parameter sets the papers give, the published controller design, the
flexibility estimates, and the hardware facts the repair's plausibility notes quote (gear ratio,
rotor inertia, backlash, bus, torque interface).

File format (every key optional except ``name``)::

    name: d2r2
    urdf: d2r2.urdf                      # file beside this one (named robots)
    loads: {none: d2r2.urdf, max: d2r2_loaded.urdf}
    gravity: false                       # does gravity act on the joints
    plane: horizontal                    # horizontal | vertical | null
    summary: "..."                       # one line for listings
    n: 2
    link_lengths: [0.30, 0.30]          # m, for task-space metrics
    drive: direct                        # direct | geared | qdd | unknown
    gear_ratio: 1                        # joint : rotor
    rotor_inertia: null                  # kg m^2, motor side
    motor: Compumotor DM1015-B
    gearbox: null                        # e.g. planetary
    backlash_deg: null
    bus: null                            # e.g. CAN
    bus_latency: null                    # s
    torque_limits: [31.2, 31.2]          # N m, physical actuator limits
    torque_interface: null               # link_side (the command is a link-side joint torque closed
                                         # by the maker's torque loop: rotor, gears inside it) | motor
    sample_rate: 2500                    # Hz, the controller rate of the hardware
    closed_form_regressor: d2r2          # the paper's regressor, whose parameters parameter_sets hold:
                                         # d2r2 (JS eq. 15, also a key of spong.CLOSED_FORM_SLOTINE_LI),
                                         # imi_scara (CI section 5), or null
    parameter_sets:                      # name -> parameter vector of the closed-form regressor
      unloaded: [0.678, 0.033, 0.029]
    load_intervals:                      # name -> [low, high], the payload box (Monte Carlo)
      dm2: [0.0, 1.1841]
    controller_design:                   # published robust-control design (all keys optional)
      K: [30.0, 10.0]                    # N m s/rad, on r = q~' + Lambda q~ (JS eq. 11)
      Lambda: [50.0, 20.0]               # 1/s
      rho_sp1: 0.1062                    # SP1 bound ||theta - theta0||
      rho_sp2: [0.053, 0.075, 0.053]     # SP2 per-parameter bounds
      zc_beta: [0.0276, 1.3254, 0.2571]  # Zenieh-Corless beta0, beta1, beta2
      br_mass_model: diag_q0             # Bascetta-Rocco M_hat: diag_q0 (constant diag M(0)) | model
    flexibility: {...}                   # physical estimates for --flexible (FLEXIBILITY_KEYS), or null
    friction_compensation_k_hat: [1, 2]  # N m, JS eqs. 89-90
    simulation:                          # closed-loop plant defaults
      plant_friction: {coulomb: [...], viscous: [...]}
      encoder_counts_per_rev: 655360     # or encoder_resolution: <rad>
      saturate: true                     # saturate the command at torque_limits

Every number about a robot lives in its file; Python modules that export a robot's numbers
under a constant name (``models.D2R2_THETA0``, ``systems.friction.D2R2_COULOMB``, ...) derive
them from :func:`packaged_description`.
"""

from __future__ import annotations

import functools
import math
import os
import pathlib
from dataclasses import dataclass, field, fields

from robust_drake.errors import RobustDrakeError
from robust_drake.robots_dir import models_dir, packaged_models_dir

__all__ = ["RobotDescription", "DEFAULT", "describe", "description_path", "load_description",
           "packaged_descriptions", "packaged_description", "ControllerDesign", "FLEXIBILITY_KEYS"]

DRIVES = ("direct", "geared", "qdd", "unknown")
#: Sample rate [Hz] of a closed loop whose robot description gives no ``sample_rate`` (JS section 8)
DEFAULT_RATE = 2500.0
TORQUE_INTERFACES = ("link_side", "motor")
#: Keys of a description's ``flexibility`` mapping (:func:`robust_drake.systems.flexibility.
#: d2r2_flexibility`): two-mass drives on every joint, the first bending mode of the last link.
FLEXIBILITY_KEYS = ("rotor_inertia", "drive_stiffness", "drive_zeta", "last_link_EI",
                    "last_link_beam_mass", "payload_inertia", "mode_zeta")


@dataclass(frozen=True)
class ControllerDesign:
    """A published robust-control design for one robot (None: not published).

    ``K`` [N m s/rad] and ``Lambda`` [1/s] are the diagonal gains of the error terms
    r = q~' + Lambda q~ (JS eq. 11); ``rho_sp1`` the SP1 bound on ||theta - theta0||_2,
    ``rho_sp2`` SP2's per-parameter bounds (JS eq. 18, table 10); ``zc_beta`` the Zenieh-Corless
    bounds (beta0, beta1, beta2) of JS eqs. 21-23 and 28; ``br_mass_model`` the Bascetta-Rocco
    controller's inertia model, ``"diag_q0"`` (BR section V: the constant M_hat = diag(M(0)))
    or ``"model"`` (M_hat(q) of the nominal model, the default)."""

    K: tuple | None = None
    Lambda: tuple | None = None
    rho_sp1: float | None = None
    rho_sp2: tuple | None = None
    zc_beta: tuple | None = None
    br_mass_model: str | None = None


@dataclass(frozen=True)
class RobotDescription:
    """Per-robot facts (SI units).  ``plant_friction`` is ``{"coulomb": [...], "viscous": [...]}``
    or None; ``encoder_resolution`` [rad] None means exact; ``saturate`` says whether the closed
    loop clamps the command at ``torque_limits`` by default.  ``parameter_sets`` maps a name to a
    parameter vector of ``closed_form_regressor``; ``load_intervals`` a payload quantity to its
    [low, high] box; ``controller_design`` the published gains and bounds; ``flexibility`` the
    physical estimates behind ``--flexible`` (keys :data:`FLEXIBILITY_KEYS`).
    ``torque_interface`` is ``"link_side"`` when the command is a link-side joint torque closed by
    the manufacturer's own torque loop on joint torque sensors: rotor inertia, gear ratio and
    motor-side friction then sit inside that loop and are not part of the model a user's
    controller sees (``gear_ratio``/``rotor_inertia`` null is then a fact, not a gap)."""

    name: str
    urdf: str | None = None
    loads: dict = field(default_factory=dict)
    gravity: bool = True
    plane: str | None = None
    summary: str = ""
    n: int | None = None
    link_lengths: tuple = ()
    drive: str = "unknown"
    gear_ratio: float | None = None
    rotor_inertia: float | None = None
    motor: str | None = None
    gearbox: str | None = None
    backlash_deg: float | None = None
    bus: str | None = None
    bus_latency: float | None = None
    torque_limits: tuple | None = None
    torque_interface: str | None = None
    sample_rate: float | None = None
    closed_form_regressor: str | None = None
    flexibility: dict | None = None
    parameter_sets: dict = field(default_factory=dict)
    load_intervals: dict = field(default_factory=dict)
    controller_design: ControllerDesign = field(default_factory=ControllerDesign)
    friction_compensation_k_hat: tuple | None = None
    plant_friction: dict | None = None
    encoder_resolution: float | None = None
    saturate: bool = False
    source: str | None = None  # the file it was read from

    def closed_loop_defaults(self) -> dict:
        """``plant_friction``, ``encoder_resolution``, ``torque_limit`` and ``rate`` defaults of
        ``ClosedLoopConfig`` for this robot (``rate``: ``sample_rate``, else :data:`DEFAULT_RATE`)."""
        pf = self.plant_friction
        return {
            "rate": float(self.sample_rate) if self.sample_rate else DEFAULT_RATE,
            "plant_friction": None if pf is None else {k: list(pf[k]) for k in ("coulomb", "viscous")},
            "encoder_resolution": self.encoder_resolution,
            "torque_limit": list(self.torque_limits) if self.saturate and self.torque_limits else None,
        }

    @property
    def geared(self) -> bool:
        """True when a gear stage sits between rotor and joint (gear ratio > 1)."""
        return self.gear_ratio is not None and self.gear_ratio > 1


DEFAULT = RobotDescription(name="default")


def _opt_float(x, what, path, signed=False):
    if x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise RobustDrakeError(f"{path}: {what} must be a number (got {x!r})") from None
    if not math.isfinite(v) or (v < 0 and not signed):
        raise RobustDrakeError(f"{path}: {what} must be a finite number{'' if signed else ' >= 0'} (got {x!r})")
    return v


def _opt_tuple(x, what, path, signed=False):
    if x is None:
        return None
    if not isinstance(x, (list, tuple)):
        raise RobustDrakeError(f"{path}: {what} must be a list of numbers (got {x!r})")
    return tuple(_opt_float(v, what, path, signed) for v in x)


def _mapping(x, what, path) -> dict:
    if x is None:
        return {}
    if not isinstance(x, dict):
        raise RobustDrakeError(f"{path}: {what} must be a mapping (got {x!r})")
    return x


def _parameter_sets(doc, path) -> dict:
    """``parameter_sets``: name -> parameter vector (signed numbers)."""
    sets = _mapping(doc.get("parameter_sets"), "parameter_sets", path)
    return {str(k): _opt_tuple(v, f"parameter_sets.{k}", path, signed=True) for k, v in sets.items()}


def _load_intervals(doc, path) -> dict:
    """``load_intervals``: name -> (low, high) with low <= high."""
    out = {}
    for k, v in _mapping(doc.get("load_intervals"), "load_intervals", path).items():
        iv = _opt_tuple(v, f"load_intervals.{k}", path, signed=True)
        if len(iv) != 2 or iv[0] > iv[1]:
            raise RobustDrakeError(f"{path}: load_intervals.{k} must be [low, high] with low <= high (got {v!r})")
        out[str(k)] = iv
    return out


def _controller_design(doc, path) -> ControllerDesign:
    d = _mapping(doc.get("controller_design"), "controller_design", path)
    known = {f.name for f in fields(ControllerDesign)}
    if set(d) - known:
        raise RobustDrakeError(f"{path}: unknown controller_design keys {sorted(set(d) - known)}; known: {sorted(known)}")
    mm = d.get("br_mass_model")
    if mm not in (None, "diag_q0", "model"):
        raise RobustDrakeError(f"{path}: controller_design.br_mass_model must be diag_q0 or model (got {mm!r})")
    return ControllerDesign(**{k: (v if k == "br_mass_model" else _opt_float(v, f"controller_design.{k}", path)
                                   if k == "rho_sp1" else _opt_tuple(v, f"controller_design.{k}", path))
                               for k, v in d.items()})


def _flexibility(doc, path) -> dict | None:
    f = doc.get("flexibility")
    if f is None:
        return None
    f = _mapping(f, "flexibility", path)
    if set(f) != set(FLEXIBILITY_KEYS):
        raise RobustDrakeError(f"{path}: flexibility needs exactly the keys {', '.join(FLEXIBILITY_KEYS)}")
    return {k: (_opt_tuple(v, f"flexibility.{k}", path) if isinstance(v, (list, tuple))
                else _opt_float(v, f"flexibility.{k}", path)) for k, v in f.items()}


def _simulation(sim, path) -> dict:
    """The ``simulation`` block: plant friction, encoder resolution [rad], saturate."""
    allowed = {"plant_friction", "encoder_counts_per_rev", "encoder_resolution", "saturate"}
    if set(sim) - allowed:
        raise RobustDrakeError(f"{path}: unknown keys {sorted(set(sim) - allowed)} in simulation")
    pf = sim.get("plant_friction")
    if pf is not None and (not isinstance(pf, dict) or set(pf) != {"coulomb", "viscous"}):
        raise RobustDrakeError(f"{path}: simulation.plant_friction needs keys coulomb and viscous")
    enc = _opt_float(sim.get("encoder_resolution"), "encoder_resolution", path)
    if sim.get("encoder_counts_per_rev") is not None:
        enc = 2.0 * math.pi / _opt_float(sim["encoder_counts_per_rev"], "encoder_counts_per_rev", path)
    return {"plant_friction": None if pf is None else {k: list(_opt_tuple(pf[k], k, path)) for k in ("coulomb", "viscous")},
            "encoder_resolution": enc, "saturate": bool(sim.get("saturate", False))}


def _parse(doc: dict, path: str) -> RobotDescription:
    if not isinstance(doc, dict) or "name" not in doc:
        raise RobustDrakeError(f"{path}: a robot description is a mapping with at least 'name'")
    doc = dict(doc)
    sim = _simulation(_mapping(doc.pop("simulation", None), "simulation", path), path)
    known = {f.name for f in fields(RobotDescription)} - {"plant_friction", "encoder_resolution", "saturate", "source"}
    unknown = set(doc) - known
    if unknown:
        raise RobustDrakeError(f"{path}: unknown keys {sorted(unknown)}")
    drive = doc.get("drive", "unknown")
    if drive not in DRIVES:
        raise RobustDrakeError(f"{path}: drive must be one of {', '.join(DRIVES)} (got {drive!r})")
    interface = doc.get("torque_interface")
    if interface is not None and interface not in TORQUE_INTERFACES:
        raise RobustDrakeError(f"{path}: torque_interface must be one of {', '.join(TORQUE_INTERFACES)} or null "
                               f"(got {interface!r})")
    n = doc.get("n")
    loads = doc.get("loads") or ({"none": doc["urdf"]} if doc.get("urdf") else {})
    if not isinstance(loads, dict):
        raise RobustDrakeError(f"{path}: loads must map a load name to a URDF file")
    return RobotDescription(
        name=str(doc["name"]), urdf=doc.get("urdf"), loads={str(k): str(v) for k, v in loads.items()},
        gravity=bool(doc.get("gravity", True)), plane=doc.get("plane"), summary=str(doc.get("summary", "")),
        n=None if n is None else int(n),
        link_lengths=_opt_tuple(doc.get("link_lengths"), "link_lengths", path) or (),
        drive=drive, gear_ratio=_opt_float(doc.get("gear_ratio"), "gear_ratio", path),
        rotor_inertia=_opt_float(doc.get("rotor_inertia"), "rotor_inertia", path),
        motor=doc.get("motor"), gearbox=doc.get("gearbox"),
        backlash_deg=_opt_float(doc.get("backlash_deg"), "backlash_deg", path),
        bus=doc.get("bus"), bus_latency=_opt_float(doc.get("bus_latency"), "bus_latency", path),
        torque_limits=_opt_tuple(doc.get("torque_limits"), "torque_limits", path), torque_interface=interface,
        sample_rate=_opt_float(doc.get("sample_rate"), "sample_rate", path),
        closed_form_regressor=doc.get("closed_form_regressor"), flexibility=_flexibility(doc, path),
        parameter_sets=_parameter_sets(doc, path), load_intervals=_load_intervals(doc, path),
        controller_design=_controller_design(doc, path),
        friction_compensation_k_hat=_opt_tuple(doc.get("friction_compensation_k_hat"), "k_hat", path),
        source=path, **sim,
    )


@functools.lru_cache(maxsize=64)
def _load_cached(path: str, mtime: float) -> RobotDescription:
    import yaml

    try:
        with open(path) as fh:
            doc = yaml.safe_load(fh)
    except (OSError, yaml.YAMLError) as exc:
        raise RobustDrakeError(f"could not read robot description {path}: {exc}") from None
    return _parse(doc, path)


def load_description(path) -> RobotDescription:
    """The description in the YAML file ``path``."""
    p = os.fspath(path)
    return _load_cached(p, os.path.getmtime(p))


def description_path(robot) -> pathlib.Path | None:
    """The description file of ``robot`` (name or URDF path), or None if it has none."""
    text = os.fspath(robot)
    if text in {d.name for d in packaged_descriptions(packaged_models_dir())}:  # ROBUST_DRAKE_MODELS may hold its own description, else the packaged one
        p = models_dir() / f"{text}.yaml"
        p = p if p.is_file() else packaged_models_dir() / f"{text}.yaml"
    elif text.endswith((".urdf", ".sdf")):
        p = pathlib.Path(text).expanduser().with_suffix(".yaml")
    else:
        return None
    return p if p.is_file() else None


def describe(robot) -> RobotDescription:
    """The :class:`RobotDescription` of ``robot``; :data:`DEFAULT` (named after the robot) when
    it has no description file."""
    p = description_path(robot)
    if p is None:
        return RobotDescription(name=str(robot))
    return load_description(p)


def packaged_descriptions(folder) -> list[RobotDescription]:
    """Every ``*.yaml`` description in ``folder`` (the shipped robots), sorted by file name."""
    return [load_description(p) for p in sorted(pathlib.Path(folder).glob("*.yaml"))]


def packaged_description(name: str) -> RobotDescription:
    """The description shipped for the named robot (``robust_drake/robots/<name>.yaml``), whatever
    ``ROBUST_DRAKE_MODELS`` says: the source of the paper numbers modules export as constants."""
    p = packaged_models_dir() / f"{name}.yaml"
    if not p.is_file():
        raise RobustDrakeError(f"no shipped robot description {name!r} ({p})")
    return load_description(p)
