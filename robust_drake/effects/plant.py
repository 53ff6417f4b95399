"""Effects that change the plant itself rather than add a force: reflected rotor inertia and a
payload at the tool. Their ``block`` is ``None``; :meth:`Effect.apply_to_plant` (before
``Finalize``) or :meth:`Effect.apply_to_context` realise them, so Drake's mass matrix holds the
term. Also the plant loader that applies them (:func:`load_plant`).
"""

from __future__ import annotations

import math

import numpy as np

from robust_drake.effects.base import Effect
from robust_drake.errors import RobustDrakeError


class RotorInertia(Effect):
    """Reflected motor inertia ``I_r qdd_j`` on the diagonal of M (``reflected_inertia`` = rotor
    inertia x gear ratio^2, kg m^2). Realised in the plant by the joint actuator's rotor inertia
    (an actuator is added if the joint has none). On the first joint of a serial arm it merges
    with the first link's inertia (not identifiable); the columns are still given."""

    kind = "rotor_inertia"
    coef_names = ("reflected_inertia",)
    bounds = {"reflected_inertia": (0.0, math.inf)}  # an inertia is >= 0
    needs_qdd = True
    modifies_plant = True
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        if qdd is None:
            raise RobustDrakeError("rotor_inertia columns need accelerations (data.qdd)")
        return qdd[:, j:j + 1]

    def block(self, n, parameters, **kw):
        return None

    def apply_to_plant(self, plant, parameters):
        from pydrake.multibody.tree import JointActuatorIndex
        vals = parameters["reflected_inertia"]
        # Pre-Finalize: the arm's 1-dof joints in index order are its coordinates 0..n-1.
        joints = [plant.get_joint(ji) for ji in plant.GetJointIndices()
                  if plant.get_joint(ji).num_velocities() == 1]
        js = self.joints(len(joints))
        vals = list(vals) if isinstance(vals, (list, tuple, np.ndarray)) else [vals] * len(js)
        for j, Ir in zip(js, vals):
            joint = joints[j]
            act = None
            for ai in plant.GetJointActuatorIndices():
                a = plant.get_joint_actuator(ai)
                if a.joint().index() == joint.index():
                    act = a
            if act is None:
                act = plant.AddJointActuator(f"rotor_{j}", joint)
            G = act.default_gear_ratio()
            act.set_default_rotor_inertia(act.default_rotor_inertia() + float(Ir) / (G * G))

    def apply_to_context(self, plant, context, parameters):
        """Post-Finalize alternative to :meth:`apply_to_plant` (use one, not both): raise the
        joint actuator's rotor inertia in ``context``. Needs an actuator on the joint."""
        vals = parameters["reflected_inertia"]
        js = self.joints(plant.num_velocities())
        vals = list(vals) if isinstance(vals, (list, tuple, np.ndarray)) else [vals] * len(js)
        for j, Ir in zip(js, vals):
            act = None
            for ai in plant.GetJointActuatorIndices():
                a = plant.get_joint_actuator(ai)
                if a.joint().num_velocities() == 1 and a.joint().velocity_start() == j:
                    act = a
            if act is None:
                raise RobustDrakeError(f"rotor_inertia: joint {j + 1} has no actuator; use apply_to_plant "
                                       "(load_plant(robot, effects)) before Finalize instead")
            G = act.gear_ratio(context)
            act.SetRotorInertia(context, act.rotor_inertia(context) + float(Ir) / (G * G))


class Payload(Effect):
    """Point mass ``mass`` [kg] at the tool (a point fixed in the last link, ``tool_position``
    in that body's frame, default from the robot's ArmSpec / the last link's COM direction).

    Columns: inverse dynamics of a 1 kg point mass at the tool (with gravity), computed with the
    Drake plant of ``robot`` (given to :func:`make_effect` / ``candidates(robot=...)`` or found
    as ``data.robot``). Realised in the plant by welding a point-mass body to the last link.

    Identifiability: a mass rigidly attached to the last link only changes that link's inertial
    parameters, so when all base parameters are fitted freely the payload is absorbed by them
    (its column lies in the span of the rigid-body regressor); it is separable only against a
    prior / nominal rigid-body model."""

    kind = "payload"
    bounds = {"mass": (0.0, math.inf)}
    coef_names = ("mass",)
    modifies_plant = True
    needs_qdd = True
    shared = True
    default_shape = {"robot": None, "tool_position": None}

    @classmethod
    def candidates(cls, n_joints, robot=None, **context):
        return [cls(joint=None, robot=robot)]

    def _tool(self, plant):
        return _tool_point(plant, self.shape["tool_position"])

    def evaluate_columns(self, q, qd=None, qdd=None, tau=None, taud=None, robot=None):
        robot = robot or self.shape["robot"]
        if robot is None:
            raise RobustDrakeError("payload columns need the robot (make_effect('payload', robot=...))")
        if qd is None or qdd is None:
            raise RobustDrakeError("payload columns need qd and qdd")
        plant, context, body, p = _payload_plant(robot, self.shape["tool_position"])
        q, qd, qdd = (np.atleast_2d(a) for a in (q, qd, qdd))
        N, n = q.shape
        from pydrake.multibody.tree import MultibodyForces
        f = MultibodyForces(plant)
        cols = np.zeros((N, n, 1))
        for i in range(N):
            plant.SetPositions(context, q[i])
            plant.SetVelocities(context, qd[i])
            plant.CalcForceElementsContribution(context, f)
            cols[i, :, 0] = plant.CalcInverseDynamics(context, qdd[i], f)
        return cols

    def columns(self, data):
        robot = self.shape["robot"] or getattr(data, "robot", None)
        cols = self.evaluate_columns(data.q, data.qd, data.qdd, robot=robot)
        return cols, self.column_names(np.asarray(data.q).shape[1])

    def block(self, n, parameters, **kw):
        return None

    def mass_from_base_shift(self, data, regressor, theta_base, theta_base_nominal=None) -> float:
        """Payload mass implied by a fitted rigid-body model that absorbed it.

        A tool mass lies in the span of the rigid-body regressor (class docstring), so a free
        fit absorbs it into the base parameters. Its size is recovered by projecting the torque
        difference between the fitted and the nominal (URDF) base parameters onto the payload
        column: ``m = <Phi, Y_b dtheta> / <Phi, Phi>`` over the samples of ``data``
        (``Y_b`` = ``regressor.evaluate``, ``dtheta = theta_base - theta_base_nominal``).
        """
        Yb = np.asarray(regressor.evaluate(data.q, data.qd, data.qdd), float)
        if theta_base_nominal is None:
            theta_base_nominal = regressor.base_parameters()
        dtau = Yb @ (np.asarray(theta_base, float) - np.asarray(theta_base_nominal, float))
        robot = self.shape["robot"] or getattr(data, "robot", None)
        phi = self.evaluate_columns(data.q, data.qd, data.qdd, robot=robot)[:, :, 0]
        return float(np.sum(phi * dtau) / np.sum(phi * phi))

    def apply_to_context(self, plant, context, parameters):
        """Post-Finalize alternative to :meth:`apply_to_plant` (use one, not both): add the point
        mass to the tool body's spatial inertia in ``context``."""
        from pydrake.multibody.tree import SpatialInertia, UnitInertia
        m = float(parameters["mass"])
        body, p = self._tool(plant)
        M = body.CalcSpatialInertiaInBodyFrame(context)
        M += SpatialInertia(m, p, UnitInertia.PointMass(p), skip_validity_check=True)
        body.SetSpatialInertiaInBodyFrame(context, M)

    def apply_to_plant(self, plant, parameters):
        from pydrake.math import RigidTransform
        from pydrake.multibody.tree import SpatialInertia, UnitInertia
        m = float(parameters["mass"])
        body, p = self._tool(plant)
        pl = plant.AddRigidBody("payload", body.model_instance(),
                                SpatialInertia(m, np.zeros(3), UnitInertia(0.0, 0.0, 0.0),
                                               skip_validity_check=True))
        plant.WeldFrames(body.body_frame(), pl.body_frame(), RigidTransform(p))


def _last_body(plant):
    """The child body of the arm's last 1-dof joint (joint index order; works pre-Finalize)."""
    joints = [plant.get_joint(ji) for ji in plant.GetJointIndices()
              if plant.get_joint(ji).num_velocities() == 1]
    if not joints:
        raise RobustDrakeError("payload: the model has no 1-dof joint")
    return joints[-1].child_body()


def _tool_point(plant, tool_position=None):
    """(body, p_BT): the tool point. ``tool_position`` (in the last link's frame) if given, else
    the frame named ``tool`` (URDF ``<frame name="tool" link=...>``) if the model has one, else
    twice the last link's COM offset (the far end of a uniform rod)."""
    if tool_position is not None:
        return _last_body(plant), np.asarray(tool_position, dtype=float)
    if plant.HasFrameNamed("tool"):
        frame = plant.GetFrameByName("tool")
        return frame.body(), np.asarray(frame.GetFixedPoseInBodyFrame().translation(), dtype=float)
    body = _last_body(plant)
    return body, 2.0 * np.asarray(body.default_com(), dtype=float)


_PAYLOAD_CACHE: dict = {}


def _payload_plant(robot, tool_position):
    """A plant of ``robot`` whose links are massless except a 1 kg point at the tool."""
    key = (str(robot), None if tool_position is None else tuple(tool_position))
    if key in _PAYLOAD_CACHE:
        return _PAYLOAD_CACHE[key]
    from pydrake.multibody.tree import SpatialInertia, UnitInertia
    plant = load_plant(robot)
    context = plant.CreateDefaultContext()
    body, p = _tool_point(plant, tool_position)
    from pydrake.multibody.tree import BodyIndex
    zero = SpatialInertia(0.0, np.zeros(3), UnitInertia(0.0, 0.0, 0.0), skip_validity_check=True)
    for bi in range(1, plant.num_bodies()):
        plant.get_body(BodyIndex(bi)).SetSpatialInertiaInBodyFrame(context, zero)
    body.SetSpatialInertiaInBodyFrame(
        context, SpatialInertia(1.0, p, UnitInertia.PointMass(p), skip_validity_check=True))
    for ai in plant.GetJointActuatorIndices():  # no reflected rotor inertia either
        plant.get_joint_actuator(ai).SetRotorInertia(context, 0.0)
    out = (plant, context, body, p)
    _PAYLOAD_CACHE[key] = out
    return out


def load_plant(robot, effects=(), time_step=0.0, builder=None):
    """``robust_drake.models.make_plant`` (or ``add_arm`` into ``builder``) with the
    plant-modifying effects [(Effect, parameters), ...] applied before ``Finalize``. Returns the
    plant."""
    from robust_drake.models import add_arm, make_plant

    def apply(plant):
        for eff, params in effects:
            eff.apply_to_plant(plant, params)

    if builder is not None:
        return add_arm(builder, robot, time_step=time_step, before_finalize=apply)[0]
    return make_plant(robot, time_step=time_step, before_finalize=apply)


def resolve_robot_path(robot) -> str:
    """Path of ``robot``'s model file (``robust_drake.models.resolve_urdf``)."""
    from robust_drake.models import resolve_urdf

    return str(resolve_urdf(robot))
