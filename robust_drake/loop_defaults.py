"""The defaults of one closed loop, in one place: :class:`robust_drake.diagram.ClosedLoopConfig`
and the batch :class:`robust_drake.scenario.Scenario` (plain-data overrides of it) both take
their field defaults from here, so a batch row and ``rd.simulate`` with the same overrides run the
same loop. Robot-dependent defaults (``rate``, ``plant_friction``, ``encoder_resolution``,
``torque_limit``) come from the robot's description (``RobotDescription.closed_loop_defaults``)."""

from __future__ import annotations

#: field -> default of the fields ClosedLoopConfig and Scenario share (dict fields: empty)
LOOP_DEFAULTS = {
    "robot": "d2r2",
    "load": "none",
    "controller": "sp1",
    "trajectory": "cpt",
    "observer": "averaging",
    "friction_compensation": False,
    "duration": None,
    "true_theta": None,
}


def robot_rate(robot) -> float:
    """The controller rate [Hz] of ``robot``'s description (``sample_rate``, else 2500)."""
    from robust_drake.description import describe

    return float(describe(robot).closed_loop_defaults()["rate"])
