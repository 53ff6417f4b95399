"""Arm models: URDF lookup, Drake plants, and the paper parameter sets.

Every arm of the project is a URDF file shipped as package data in ``robust_drake/robots/``
(found through ``importlib.resources``, so it works from a checkout and from an installed wheel;
the repository's top-level ``models/`` is a symlink to that folder).  Override the folder with the
environment variable ``ROBUST_DRAKE_MODELS``.  Conventions shared by all files:

- joints ``joint1`` .. ``jointn`` (revolute), one actuator ``motor<i>`` per joint; position limits
  where the arm has them (``<limit lower upper>``, read by :meth:`ArmSpec.position_limits`; the
  papers' arms are unlimited);
- link ``i`` has its origin on joint ``i`` and its x axis along the link;
- a frame ``tool`` at the tip of the last link (forward kinematics:
  ``plant.GetFrameByName("tool")``);
- no joint damping or friction in the URDF (friction is a separate effect block);
- reflected rotor inertia, where an arm has gears, is given the Drake way
  (``<transmission>`` with ``drake:rotor_inertia`` and ``drake:gear_ratio``), so the plant's mass
  matrix contains ``kr^2 Ir`` on the diagonal.

The named robots (:data:`ROBOTS`) are the robot descriptions shipped beside the URDFs
(``robots/<name>.yaml``, :mod:`robust_drake.description`).

D2R2 numbers (Jaritz & Spong, seeds/001, appendix): tables 8, 9, 11 and eq. 93, kept in the
robot's description ``robots/d2r2.yaml`` (the ``D2R2_*`` constants here are read from it).  The
link lengths are not printed; see ``models/d2r2.urdf`` and BUILD_NOTES.md ("Models and
regressors") for the derivation of l1 = l2 = 0.30 m.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import pathlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from robust_drake.description import packaged_description, packaged_descriptions
from robust_drake.errors import RobustDrakeError
from robust_drake.robots_dir import MODELS_DIR, models_dir, packaged_models_dir  # noqa: F401  (re-exported)

__all__ = [
    "MODELS_DIR",
    "ROBOTS",
    "ArmSpec",
    "JointLimits",
    "get_arm",
    "packaged_models_dir",
    "models_dir",
    "resolve_urdf",
    "make_plant",
    "add_arm",
    "D2R2_THETA_UNLOADED",
    "D2R2_THETA_LOADED",
    "D2R2_THETA0",
    "D2R2_LOAD_INTERVALS",
    "D2R2_TORQUE_LIMIT",
    "d2r2_theta",
    "d2r2_theta_from_plant",
    "set_d2r2_theta",
]


@dataclass(frozen=True)
class JointLimits:
    """Position limits of an arm's joints, one entry per generalized position (plant order).

    ``lower``/``upper`` [rad for revolute, m for prismatic joints] are ``-inf``/``+inf`` where the
    URDF gives none (``continuous`` joints, or no ``<limit>``); ``names`` are the URDF joint names.
    A continuous-time ``MultibodyPlant`` does not enforce them: they are checked on the reference
    (:func:`robust_drake.trajectories.check_within_limits`).
    """

    lower: tuple
    upper: tuple
    names: tuple
    units: tuple  # "rad" or "m" per position

    @classmethod
    def from_plant(cls, plant) -> "JointLimits":
        """The finalized ``plant``'s ``GetPositionLowerLimits()/GetPositionUpperLimits()``, with
        the name and unit of the joint owning each position."""
        n = plant.num_positions()
        names, units = [""] * n, ["rad"] * n
        for ji in plant.GetJointIndices():
            j = plant.get_joint(ji)
            for k in range(j.num_positions()):
                names[j.position_start() + k] = j.name()
                units[j.position_start() + k] = "m" if j.type_name() == "prismatic" else "rad"
        return cls(tuple(float(x) for x in plant.GetPositionLowerLimits()),
                   tuple(float(x) for x in plant.GetPositionUpperLimits()), tuple(names), tuple(units))

    @classmethod
    def unlimited(cls, n: int) -> "JointLimits":
        """No limit on any of ``n`` revolute joints (names ``joint1``..``jointn``)."""
        return cls((-math.inf,) * n, (math.inf,) * n, tuple(f"joint{i + 1}" for i in range(n)), ("rad",) * n)

    @property
    def n(self) -> int:
        return len(self.lower)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) as float arrays of shape (n,)."""
        return np.asarray(self.lower, float), np.asarray(self.upper, float)

    def any_finite(self) -> bool:
        return bool(np.isfinite(self.lower).any() or np.isfinite(self.upper).any())


@functools.lru_cache(maxsize=32)
def _urdf_limits(robot: str) -> JointLimits:
    return JointLimits.from_plant(make_plant(robot))


@dataclass(frozen=True)
class ArmSpec:
    """A named arm: which URDF, how many joints, the geometry the papers use.

    ``loads`` maps a load name to a URDF file name (the default load is ``"none"``).
    ``torque_limits`` are the physical actuator limits in N m (informative; the URDFs do not
    clamp, controllers that want saturation apply it themselves).  ``joint_limits`` are the joint
    position limits; None (the default) reads them from the URDF through Drake on first use
    (:meth:`position_limits`).
    """

    name: str
    urdf: str
    n: int
    link_lengths: tuple
    gravity: bool
    plane: str | None
    loads: dict = field(default_factory=dict)
    description: str = ""
    torque_limits: tuple | None = None
    joint_limits: JointLimits | None = None

    def position_limits(self) -> JointLimits:
        """The joint position limits: ``joint_limits`` when given, else the URDF's as Drake reads
        them (``plant.GetPositionLowerLimits()/GetPositionUpperLimits()``; +-inf for continuous
        joints), cached per URDF.  An arm whose ``urdf`` is neither a named robot nor a
        ``.urdf``/``.sdf`` path has no known limits (all infinite)."""
        if self.joint_limits is not None:
            return self.joint_limits
        if self.name in ROBOTS:
            return _urdf_limits(self.name)
        if str(self.urdf) in ROBOTS or str(self.urdf).endswith((".urdf", ".sdf")):
            return _urdf_limits(str(self.urdf))
        return JointLimits.unlimited(self.n)


_D2R2 = packaged_description("d2r2")  # the one source of the D2R2 numbers below
D2R2_TORQUE_LIMIT = _D2R2.torque_limits[0]  # N m, JS section 1 (+-8 V command, Compumotor DM1015-B)


def _named_robots() -> dict[str, ArmSpec]:
    """One :class:`ArmSpec` per shipped robot description (``robots/<name>.yaml``, see
    :mod:`robust_drake.description`)."""
    return {d.name: ArmSpec(name=d.name, urdf=d.urdf, n=d.n, link_lengths=d.link_lengths,
                            gravity=d.gravity, plane=d.plane, loads=dict(d.loads),
                            description=d.summary, torque_limits=d.torque_limits)
            for d in packaged_descriptions(packaged_models_dir())}


#: The named robots, read from the shipped descriptions (d2r2, imi_scara, siciliano_2link,
#: dfki_double_pendulum_c1/_a0, serial7).
ROBOTS: dict[str, ArmSpec] = _named_robots()


def get_arm(name: str) -> ArmSpec:
    """The :class:`ArmSpec` called ``name``; RobustDrakeError listing the known names otherwise."""
    try:
        return ROBOTS[name]
    except (KeyError, TypeError):
        from robust_drake.errors import did_you_mean

        raise RobustDrakeError(
            f"unknown robot {name!r}{did_you_mean(str(name), ROBOTS)}; known robots: {', '.join(sorted(ROBOTS))}"
        ) from None


def resolve_urdf(robot: str | os.PathLike, load: str = "none") -> pathlib.Path:
    """Path of the URDF for ``robot`` (a name in ROBOTS, or a path to a ``.urdf`` file).

    ``load`` selects a load variant of a named robot (``get_arm(robot).loads``); a path accepts
    only ``load="none"``.
    """
    text = os.fspath(robot)
    if text in ROBOTS:
        spec = ROBOTS[text]
        if load not in spec.loads:
            raise RobustDrakeError(
                f"robot {text!r} has no load {load!r}; available loads: {', '.join(spec.loads)}"
            )
        path = models_dir() / spec.loads[load]
        if not path.is_file():
            hint = ("check ROBUST_DRAKE_MODELS" if os.environ.get("ROBUST_DRAKE_MODELS")
                    else "the installed package lacks its URDF data; reinstall robust_drake")
            raise RobustDrakeError(
                f"URDF for robot {text!r} (load {load!r}) not found at {path}; {hint}"
            )
        return path
    if text.endswith((".urdf", ".sdf")):
        path = pathlib.Path(text).expanduser()
        if not path.is_file():
            raise RobustDrakeError(f"URDF file {path} does not exist")
        if load != "none":
            raise RobustDrakeError(
                f"load {load!r} given for a URDF path; load variants exist only for named robots"
            )
        return path.resolve()
    from robust_drake.errors import did_you_mean

    raise RobustDrakeError(
        f"unknown robot {text!r}{did_you_mean(text, ROBOTS)}: give one of {', '.join(sorted(ROBOTS))} "
        "or a path to a .urdf/.sdf file"
    )


#: Joint types an arm may have (Drake's names; a URDF ``continuous`` joint is a ``revolute`` one).
SUPPORTED_JOINT_TYPES = ("revolute", "prismatic", "weld")

_log = logging.getLogger("robust_drake.models")
_WELD_REPORTED: set = set()


def _parse_into(plant, robot, load):
    from pydrake.multibody.parsing import Parser

    path = resolve_urdf(robot, load)
    try:
        instances = Parser(plant).AddModels(str(path))
    except RuntimeError as exc:  # Drake parser errors
        raise RobustDrakeError(f"could not parse {path}: {exc}") from exc
    return path, instances


def _root_bodies(plant, instances):
    """Bodies of the parsed model instances with no joint to a parent (pre-Finalize)."""
    children = {plant.get_joint(j).child_body().index() for j in plant.GetJointIndices()}
    return [b for mi in instances for b in (plant.get_body(i) for i in plant.GetBodyIndices(mi))
            if b.index() not in children]


def _urdf_parent_joint(path, link: str):
    """(name, type, parent) of the URDF joint whose child is ``link``, read from the file itself
    (Drake drops a ``floating`` joint with a warning and keeps no trace of it); None when the
    file has none or is not a readable URDF."""
    import xml.etree.ElementTree as ET

    if not str(path).endswith(".urdf"):
        return None
    try:
        root = ET.parse(str(path)).getroot()
    except (ET.ParseError, OSError):
        return None
    for j in root.iter("joint"):
        child = j.find("child")
        if child is not None and child.get("link") == link:
            parent = j.find("parent")
            return j.get("name", "?"), j.get("type", "?"), None if parent is None else parent.get("link")
    return None


def _refuse_mimic(path) -> None:
    """RobustDrakeError naming a ``<mimic>`` joint: Drake turns it into a coupler constraint, which
    a continuous-time plant does not support, and its column would count as a joint of its own."""
    import xml.etree.ElementTree as ET

    if not str(path).endswith(".urdf"):
        return
    try:
        root = ET.parse(str(path)).getroot()
    except (ET.ParseError, OSError):
        return
    for j in root.iter("joint"):
        m = j.find("mimic")
        if m is not None:
            raise RobustDrakeError(
                f"{path}: joint {j.get('name')!r} mimics joint {m.get('joint')!r} (a coupled joint, q = "
                f"{m.get('multiplier', '1')} q_{m.get('joint')} + {m.get('offset', '0')}): coupled joints are not supported "
                "(a continuous-time plant has no coupler constraints, and a log has no column for it); make it a "
                "joint of its own or weld it (type=\"fixed\")")


def _weld_roots(plant, instances, path, floating_base: bool):
    """Weld the model's root link to the world (a URDF without a world joint), unless a floating
    base is asked for; returns the welded root body (None if nothing was welded).  More than one
    root (a ``floating`` URDF joint leaves a free body, or disconnected links) is refused: which
    body is the base would be a guess.  A root whose URDF joint to the world is ``floating`` is
    refused too (Drake drops such a joint, and with it the base's pose: welding at the identity
    would silently turn gravity), unless ``floating_base``."""
    roots = _root_bodies(plant, instances)
    if floating_base or not roots:
        return None
    if len(roots) > 1:
        raise RobustDrakeError(
            f"{path}: links {', '.join(repr(b.name()) for b in roots)} have no joint to a parent "
            "(a 'floating' joint or disconnected links); an arm needs one tree rooted at its base")
    joint = _urdf_parent_joint(path, roots[0].name())
    if joint is not None and joint[1] == "floating":
        raise RobustDrakeError(
            f"{path}: joint {joint[0]!r} attaches the root link {roots[0].name()!r} to {joint[2]!r} as a "
            "'floating' joint (a free-flying base; Drake drops it and its origin): a fixed-base arm needs "
            "the base welded; change its type to \"fixed\" (its origin xyz/rpy, hence the direction of "
            "gravity, is then kept), or ask for a floating base (floating_base=True)")
    plant.WeldFrames(plant.world_frame(), roots[0].body_frame())
    return roots[0]


def gravity_reaches_joints(plant, samples: int = 8, seed: int = 0) -> bool:
    """True when gravity produces a joint torque somewhere (``CalcGravityGeneralizedForces`` at
    ``samples`` random configurations in [-pi, pi]); False for an arm whose every joint axis is
    vertical (a horizontal arm, or a vertical one welded with the wrong base pose)."""
    ctx = plant.CreateDefaultContext()
    rng = np.random.default_rng(seed)
    from pydrake.multibody.tree import BodyIndex

    masses = [plant.get_body(BodyIndex(b)).default_mass() for b in range(1, plant.num_bodies())]
    mass = sum(m for m in masses if np.isfinite(m))
    tol = 1e-9 * 9.81 * max(mass, 1.0)
    for _ in range(samples):
        plant.SetPositions(ctx, rng.uniform(-np.pi, np.pi, plant.num_positions()))
        if np.abs(plant.CalcGravityGeneralizedForces(ctx)).max() > tol:
            return True
    return False


def urdf_root_links(urdf_path) -> list[str]:
    """Links of a URDF that are the child of no joint, other than ``world`` (Drake's world
    body): one for an arm written the ROS way (no world joint), none for one with a joint to
    ``world``. [] for a file that is not a readable URDF (the parser reports it)."""
    import xml.etree.ElementTree as ET

    path = os.fspath(urdf_path)
    if not path.endswith(".urdf"):
        return []
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return []
    children = {c.get("link") for j in root.iter("joint") for c in j.findall("child")}
    return [ln.get("name") for ln in root.iter("link") if ln.get("name") not in children and ln.get("name") != "world"]


def root_weld_warning(robot, plant=None) -> str | None:
    """The message for a URDF whose root link has no joint to the world (it is welded at the
    identity pose, the ROS/Pinocchio convention): None when the file has a world joint. With the
    finalized ``plant``, says whether gravity then reaches any joint (if not, a vertical arm whose
    world joint was left out is being modelled in a horizontal plane). Shown on the console by
    the loader and put into the repair's report.json / report.md warnings."""
    path = resolve_urdf(robot) if not isinstance(robot, pathlib.Path) else robot
    roots = urdf_root_links(path)
    if len(roots) != 1:
        return None
    msg = (f"{path}: root link {roots[0]!r} has no joint to the world; welded to it at the identity pose "
           "(base frame = world frame, gravity along the base's -z)")
    if plant is not None and plant.num_positions() and not gravity_reaches_joints(plant):
        msg += ("; gravity then produces NO torque on any joint: if the arm moves in a vertical plane, the "
                "URDF's world joint (with the base's rpy) is missing, add it as a \"fixed\" joint")
    return msg


def _check_joints(plant, path, floating_base: bool) -> None:
    """RobustDrakeError naming the first joint that is not revolute/prismatic/fixed (a floating
    base joint to the world is accepted when ``floating_base``)."""
    for ji in plant.GetJointIndices():
        j = plant.get_joint(ji)
        if j.type_name() in SUPPORTED_JOINT_TYPES:
            continue
        if floating_base and j.parent_body().index() == plant.world_body().index():
            continue
        raise RobustDrakeError(
            f"{path}: joint {j.name()!r} is a {j.type_name()} joint; supported are revolute "
            "(URDF revolute/continuous), prismatic and fixed joints")


def _populate(plant, robot, load, time_step, before_finalize, floating_base,
              use_sampled_output_ports):
    """The one loading sequence: parse, hook, weld the root, finalize, check the joints."""
    path, instances = _parse_into(plant, robot, load)
    _refuse_mimic(path)
    if before_finalize is not None:
        before_finalize(plant)
    welded = _weld_roots(plant, instances, path, floating_base)
    if time_step > 0 and not use_sampled_output_ports:
        plant.SetUseSampledOutputPorts(False)
    plant.Finalize()
    _check_joints(plant, path, floating_base)
    if welded is not None and str(path) not in _WELD_REPORTED:
        _WELD_REPORTED.add(str(path))
        _log.warning("%s (make_plant(..., floating_base=True) for a floating base)",
                     root_weld_warning(path, plant) or f"{path}: root link {welded.name()!r} welded to the world")
    return plant


def make_plant(robot: str, load: str = "none", time_step: float = 0.0, *,
               before_finalize: Callable | None = None, floating_base: bool = False,
               use_sampled_output_ports: bool = False):
    """A finalized, standalone ``MultibodyPlant`` of ``robot`` (no SceneGraph).

    ``robot`` is a name in :data:`ROBOTS` or a URDF/SDF path.  ``before_finalize(plant)`` is
    called after parsing and before ``Finalize()`` (add bodies, weld a payload, ...).  A root
    link without a joint to the world is welded to it (one logged message per file) unless
    ``floating_base``; joints other than revolute/prismatic/fixed raise RobustDrakeError naming
    the joint.  Gravity is Drake's default (world -z, 9.81 m/s^2); horizontal arms have their
    joint axes along world z so gravity produces no joint torque.  For a discrete plant
    (time_step > 0) the sampled output ports are switched off by default (see the pydrake
    pitfalls notes).
    """
    from pydrake.multibody.plant import MultibodyPlant

    return _populate(MultibodyPlant(time_step=float(time_step)), robot, load, time_step,
                     before_finalize, floating_base, use_sampled_output_ports)


def add_arm(builder, robot: str, load: str = "none", time_step: float = 0.0, *,
            before_finalize: Callable | None = None, floating_base: bool = False,
            use_sampled_output_ports: bool = False):
    """:func:`make_plant` added to a ``DiagramBuilder`` with ``AddMultibodyPlantSceneGraph``.

    Returns ``(plant, scene_graph)``; the plant is finalized.  Actuation input port
    ``plant.get_actuation_input_port()`` has one entry per joint (motor1..motorn, in joint
    order); state output ``plant.get_state_output_port()`` is [q, v].
    """
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph

    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=float(time_step))
    _populate(plant, robot, load, time_step, before_finalize, floating_base, use_sampled_output_ports)
    return plant, scene_graph


# --------------------------------------------------------------------------- D2R2 (JS appendix)
# theta of eq. 14 (values and sources in robots/d2r2.yaml): table 8, table 9, table 11
D2R2_THETA_UNLOADED = _D2R2.parameter_sets["unloaded"]
D2R2_THETA_LOADED = _D2R2.parameter_sets["loaded"]
D2R2_THETA0 = _D2R2.parameter_sets["theta0"]
D2R2_LOAD_INTERVALS = dict(_D2R2.load_intervals)  # eq. 93


def d2r2_theta(m1, lc1, I1, m2, lc2, I2, l1) -> np.ndarray:
    """JS eq. 14: theta = [m1 lc1^2 + m2 l1^2 + I1, m2 lc2^2 + I2, m2 l1 lc2].

    I1, I2 are the links' inertias about their centres of mass (axis perpendicular to the
    plane).  Broadcasts over array arguments (last axis of the result has length 3).
    """
    m1, lc1, I1, m2, lc2, I2, l1 = np.broadcast_arrays(
        *(np.asarray(x, dtype=float) for x in (m1, lc1, I1, m2, lc2, I2, l1))
    )
    return np.stack(
        [m1 * lc1**2 + m2 * l1**2 + I1, m2 * lc2**2 + I2, m2 * l1 * lc2], axis=-1
    )


def _check_two_link(plant):
    if plant.num_positions() != 2 or plant.num_velocities() != 2:
        raise RobustDrakeError(
            f"expected a 2-joint arm (D2R2-like), got {plant.num_positions()} positions"
        )


def d2r2_theta_from_plant(plant, context=None) -> np.ndarray:
    """theta of JS eq. 14 read from the plant's parameters in ``context``.

    Uses the mass matrix at q = 0 (JS eq. 3: d11 = theta1 + theta2 + 2 theta3,
    d12 = theta2 + theta3, d22 = theta2), so it includes welded payloads, reflected rotor
    inertia and whatever parameters the context holds.  Assumes link 2's centre of mass lies
    on the link's axis (true for the project's D2R2 files and for ``set_d2r2_theta``).
    """
    _check_two_link(plant)
    ctx = plant.CreateDefaultContext() if context is None else context.Clone()
    plant.SetPositions(ctx, np.zeros(2))
    M = plant.CalcMassMatrix(ctx)
    th2 = M[1, 1]
    th3 = M[0, 1] - th2
    th1 = M[0, 0] - th2 - 2.0 * th3
    return np.array([th1, th2, th3])


def _joint2_offset(plant):
    """l1: distance from joint 1's axis to joint 2's axis (in link 1's frame)."""
    joints = [plant.get_joint(j) for j in plant.GetJointIndices()]
    moving = [j for j in joints if j.num_velocities() == 1]
    if len(moving) != 2:
        raise RobustDrakeError("expected exactly two single-dof joints")
    j2 = moving[1]
    p = j2.frame_on_parent().GetFixedPoseInBodyFrame().translation()
    return moving[0], j2, float(math.hypot(p[0], p[1]))


def set_d2r2_theta(plant, context, theta) -> None:
    """Change the link inertial parameters in ``context`` so that the plant's theta (eq. 14)
    equals ``theta`` (used to set Monte Carlo "true" parameters).

    Realisation (l1 is fixed by the URDF): link 2 keeps its current total mass m2 when possible,
    lc2 = theta3 / (m2 l1) and I2 = theta2 - m2 lc2^2 > 0; if that is impossible, m2 is moved
    inside the feasible interval theta3^2 / (l1^2 theta2) < m2 < theta1 / l1^2 (geometric mean of
    the bounds).  Link 1 keeps m1 and gets m1 lc1^2 + I1 = theta1 - m2 l1^2.  Bodies welded to
    link 2 (a payload) are folded into link 2: their own inertia is set to zero.  A reflected
    rotor inertia on joint 1 is kept (it is part of theta1); one on joint 2 is not representable.
    Meant for horizontal arms (it moves centres of mass, which changes gravity torques).
    Raises RobustDrakeError if theta is not physically realisable
    (needs theta1 > 0, theta2 > 0, theta3^2 < theta1 theta2).
    """
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia

    _check_two_link(plant)
    theta = np.asarray(theta, dtype=float).reshape(-1)
    if theta.size != 3:
        raise RobustDrakeError(f"theta (true_theta) must hold the 3 parameters of JS eq. 14 (theta1, theta2, theta3), "
                               f"got {theta.size}: {theta.tolist()}")
    th1, th2, th3 = (float(x) for x in theta)
    if not (th1 > 0 and th2 > 0 and th3 * th3 < th1 * th2):
        raise RobustDrakeError(
            f"theta = {[th1, th2, th3]} is not physically realisable for a two-link arm "
            "(needs theta1 > 0, theta2 > 0, theta3^2 < theta1 theta2)"
        )
    j1, j2, l1 = _joint2_offset(plant)
    body1, body2 = j1.child_body(), j2.child_body()
    reflected = {}
    for a in plant.GetJointActuatorIndices():
        act = plant.get_joint_actuator(a)
        reflected[act.joint().index()] = act.calc_reflected_inertia(context)
    if reflected.get(j2.index(), 0.0) != 0.0:
        raise RobustDrakeError(
            "joint 2 has a reflected rotor inertia: the JS parameterisation (eq. 14) cannot represent it"
        )
    Ia1 = reflected.get(j1.index(), 0.0)  # adds to theta1 like a link-1 inertia
    welded2 = [b for b in plant.GetBodiesWeldedTo(body2) if b.index() != body2.index()]
    m2 = body2.get_mass(context) + sum(b.get_mass(context) for b in welded2)
    lo = th3 * th3 / (l1 * l1 * th2)
    hi = (th1 - Ia1) / (l1 * l1)
    margin = 1e-9 * hi
    if not (lo + margin < m2 < hi - margin):
        m2 = math.sqrt(max(lo, 1e-12) * hi) if lo > 0 else 0.5 * hi
    lc2 = th3 / (m2 * l1)
    I2 = th2 - m2 * lc2 * lc2
    R1 = th1 - Ia1 - m2 * l1 * l1
    if not R1 > 0:
        raise RobustDrakeError(f"theta1 = {th1} is smaller than joint 1's reflected inertia {Ia1}")
    m1 = body1.get_mass(context)
    lc1 = float(body1.CalcCenterOfMassInBodyFrame(context)[0])
    if not (m1 * lc1 * lc1 < R1):
        lc1 = math.sqrt(R1 / (2.0 * m1))
    I1 = R1 - m1 * lc1 * lc1

    def _slender(m, com_x, Izz):
        I_com = RotationalInertia(0.1 * Izz, Izz, Izz)
        return SpatialInertia.MakeFromCentralInertia(m, np.array([com_x, 0.0, 0.0]), I_com)

    body1.SetSpatialInertiaInBodyFrame(context, _slender(m1, lc1, I1))
    body2.SetSpatialInertiaInBodyFrame(context, _slender(m2, lc2, I2))
    for b in welded2:
        b.SetSpatialInertiaInBodyFrame(context, SpatialInertia.Zero())
