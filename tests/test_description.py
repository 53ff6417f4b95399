"""Robot descriptions (``robust_drake.description``): per-robot facts looked up by robot, from
the YAML file next to its URDF; a user's URDF with a description beside it gets its settings,
one without gets the neutral defaults, and the config overrides either."""

import math

import numpy as np
import pytest

from robust_drake.description import describe
from robust_drake.errors import RobustDrakeError
from robust_drake.models import ROBOTS, resolve_urdf

USER_YAML = """\
name: my_arm
n: 2
drive: qdd
gear_ratio: 9.0
rotor_inertia: 1.0e-4
motor: XM-9
gearbox: cycloidal
backlash_deg: 0.2
torque_limits: [5.0, 3.0]
simulation:
  plant_friction: {coulomb: [0.4, 0.1], viscous: [0.01, 0.02]}
  encoder_resolution: 1.0e-4
  saturate: true
"""


def _user_arm(tmp_path, yaml_text=USER_YAML):
    """A copy of the DFKI C.1 URDF under a user's name, with ``yaml_text`` beside it."""
    urdf = tmp_path / "my_arm.urdf"
    urdf.write_text(resolve_urdf("dfki_double_pendulum_c1").read_text())
    if yaml_text is not None:
        (tmp_path / "my_arm.yaml").write_text(yaml_text)
    return str(urdf)


def test_user_description_beside_the_urdf_sets_the_loop(tmp_path):
    from robust_drake.diagram import ClosedLoop, ClosedLoopConfig

    path = _user_arm(tmp_path)
    c = ClosedLoopConfig(robot=path, controller="pd", trajectory="sine").resolved()
    assert c.plant_friction == {"coulomb": [0.4, 0.1], "viscous": [0.01, 0.02]}
    assert c.encoder_resolution == 1e-4 and c.torque_limit == [5.0, 3.0]
    loop = ClosedLoop(ClosedLoopConfig(robot=path, controller="pd", trajectory="sine"))
    names = {s.get_name() for s in [loop.encoder] + loop.effect_blocks}
    assert "plant_friction" in names
    # every default is overridable in the config
    c2 = ClosedLoopConfig(robot=path, controller="pd", trajectory="sine", plant_friction=None,
                          encoder_resolution=None, torque_limit=None).resolved()
    assert (c2.plant_friction, c2.encoder_resolution, c2.torque_limit) == (None, None, None)


def test_urdf_without_description_gets_neutral_defaults(tmp_path):
    from robust_drake.diagram import ClosedLoopConfig

    path = _user_arm(tmp_path, yaml_text=None)
    d = describe(path)
    assert d.drive == "unknown" and d.closed_form_regressor is None
    c = ClosedLoopConfig(robot=path, controller="pd", trajectory="sine").resolved()
    assert (c.plant_friction, c.encoder_resolution, c.torque_limit) == (None, None, None)


def test_d2r2_description_holds_the_paper_numbers():
    """JS section 1 (31.2 N m), eq. 70 (655360 counts/rev), section 9 (k_hat = 1, 2 N m)."""
    d = describe("d2r2")
    c = d.closed_loop_defaults()
    assert c["torque_limit"] == [31.2, 31.2]
    assert math.isclose(c["encoder_resolution"], 2 * math.pi / 655360, rel_tol=1e-15)
    assert d.friction_compensation_k_hat == (1.0, 2.0)
    assert d.drive == "direct" and not d.geared and d.closed_form_regressor == "d2r2"
    # the module constants other code imports are the same numbers (one source of behaviour)
    from robust_drake.models import D2R2_TORQUE_LIMIT
    from robust_drake.systems.friction import D2R2_COULOMB, D2R2_K_HAT, D2R2_VISCOUS
    from robust_drake.systems.sensors import D2R2_THETA_M

    assert c["plant_friction"] == {"coulomb": list(D2R2_COULOMB), "viscous": list(D2R2_VISCOUS)}
    assert d.friction_compensation_k_hat == D2R2_K_HAT and c["encoder_resolution"] == D2R2_THETA_M
    assert d.torque_limits == (D2R2_TORQUE_LIMIT,) * 2


def test_plausibility_quotes_the_description(tmp_path):
    from robust_drake.model_repair.pipeline import plausibility

    path = _user_arm(tmp_path)
    txt = plausibility("rotor_inertia", {"reflected_inertia": 0.008}, path)
    assert "XM-9: gr^2 Ir = 81 x 0.0001 = 0.0081 kg m^2" in txt
    txt = plausibility("load_dependent_friction", {"load_coefficient": 0.1}, path)
    assert "9:1 cycloidal gear" in txt
    # the D2R2 is direct drive: no gear or backlash facts to quote
    assert "(" not in plausibility("rotor_inertia", {"reflected_inertia": 0.008}, "d2r2")
    assert "deg on the" not in plausibility("stribeck", {}, "d2r2")


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_every_shipped_description_matches_its_urdf(robot):
    """n and (two-link arms) the link lengths of the description are the URDF's: l1 = distance
    of joint 2's axis from joint 1's, l2 = distance of the ``tool`` frame from joint 2."""
    from robust_drake.models import _joint2_offset, make_plant

    d = describe(robot)
    plant = make_plant(robot)
    assert d.name == robot and d.n == plant.num_velocities() == len(d.link_lengths)
    if d.n == 2:
        _, j2, l1 = _joint2_offset(plant)
        tool = plant.GetFrameByName("tool")
        assert tool.body().index() == j2.child_body().index()
        l2 = np.hypot(*tool.GetFixedPoseInBodyFrame().translation()[:2])
        assert np.allclose(d.link_lengths, (l1, l2), rtol=1e-12)


@pytest.mark.parametrize("bad, match", [
    ("n: 2\n", "name"),
    ("name: x\ndrive: turbo\n", "drive"),
    ("name: x\ngear_ration: 6\n", "unknown keys"),
    ("name: x\nsimulation: {plant_friction: {coulomb: [1]}}\n", "coulomb and viscous"),
])
def test_bad_description_is_a_user_error(tmp_path, bad, match):
    with pytest.raises(RobustDrakeError, match=match):
        describe(_user_arm(tmp_path, bad))


def test_link_side_torque_interface_is_a_fact_not_a_gap(tmp_path):
    """The Panda's null gear ratio and rotor inertia are declared (commands are link-side joint
    torques); a fitted rotor inertia on such an arm is flagged, on a motor-side arm it is not."""
    from robust_drake.model_repair.pipeline import plausibility

    d = describe("panda")
    assert d.torque_interface == "link_side" and d.gear_ratio is None and d.rotor_inertia is None
    assert "link-side torques" in plausibility("rotor_inertia", {"reflected_inertia": 0.01}, "panda")
    assert "link-side" not in plausibility("rotor_inertia", {"reflected_inertia": 0.01}, _user_arm(tmp_path))
    with pytest.raises(RobustDrakeError, match="torque_interface"):
        (tmp_path / "bad").mkdir()
        describe(_user_arm(tmp_path / "bad", "name: x\ntorque_interface: sideways\n"))


def test_zc_takes_published_bounds_from_the_description_not_the_name(tmp_path):
    """A user's arm whose description publishes ZC bounds and gains gets them (no box search,
    uncertainty None) and refuses a box request; the D2R2 gets its file's values."""
    from robust_drake.registry import BuildContext
    from robust_drake.systems.controllers.zenieh_corless import make_zc

    design = "controller_design: {K: [7.0, 3.0], Lambda: [9.0, 4.0], zc_beta: [0.01, 0.9, 0.2]}\n"
    path = _user_arm(tmp_path, "name: my_arm\nn: 2\n" + design)
    ctx = BuildContext(robot=path, arm=None, load="none", n=2, period=4e-4, config=None)
    c = make_zc(ctx, epsilon=10.0)
    assert (c.beta1, c.beta2, c.K, c.Lambda, c.uncertainty) == (0.9, 0.2, (7.0, 3.0), (9.0, 4.0), None)
    with pytest.raises(RobustDrakeError, match="rel_bound/abs_bound"):
        make_zc(ctx, rel_bound=0.1)
    # the D2R2 by name: JS appendix 12.2 and section 8, the values of its file
    d = describe("d2r2").controller_design
    c = make_zc(BuildContext(robot="d2r2", arm=None, load="none", n=2, period=4e-4, config=None))
    assert (c.beta1, c.beta2, c.K, c.Lambda) == (d.zc_beta[1], d.zc_beta[2], d.K, d.Lambda)


def test_lg_uses_the_robots_own_parameter_sets(tmp_path):
    """LG / LG+ take theta_nom and the width from the robot's parameter sets (JS eqs. 44-46),
    the user's arm's own, not the D2R2's tables."""
    from robust_drake.registry import BuildContext
    from robust_drake.systems.controllers.liu_goldenberg import make_lg, make_lgplus

    sets = "closed_form_regressor: d2r2\nparameter_sets: {unloaded: [0.5, 0.1, 0.05], loaded: [0.7, 0.3, 0.15]}\n"
    ctx = BuildContext(robot=_user_arm(tmp_path, "name: my_arm\nn: 2\n" + sets), arm=None, load="none",
                       n=2, period=4e-4, config=None)
    lg, lgp = make_lg(ctx), make_lgplus(ctx)
    np.testing.assert_allclose(lg.theta_nom, [0.5, 0.1, 0.05])
    np.testing.assert_allclose(lg.width, [0.2, 0.2, 0.1])
    np.testing.assert_allclose(lgp.theta_nom, [0.6, 0.2, 0.1])
    np.testing.assert_allclose(lgp.width, [0.1, 0.1, 0.05])


def test_nonlinear_observer_takes_theta_from_the_description(tmp_path):
    """The JS eq. 85 observer's inertia comes from the robot's eq. 14 theta0; an arm without one
    is refused (it used to get the D2R2's silently)."""
    from robust_drake.registry import BuildContext
    from robust_drake.systems.nonlinear_observer import make_nonlinear

    def ctx(robot):
        return BuildContext(robot=robot, arm=None, load="none", n=2, period=4e-4, config=None)

    assert make_nonlinear(ctx("d2r2")).theta == describe("d2r2").parameter_sets["theta0"]
    with pytest.raises(RobustDrakeError, match="theta of JS eq. 14"):
        make_nonlinear(ctx("imi_scara"))
    assert tuple(make_nonlinear(ctx("imi_scara"), theta=(0.5, 0.1, 0.05)).theta) == (0.5, 0.1, 0.05)


def test_sample_rate_defaults_to_the_robots_description():
    """The closed loop's rate comes from the robot's description (Franka's control interface runs
    at 1 kHz, JS section 8's DSP at 2500 Hz), 2500 Hz where none is given; a user's rate wins."""
    from robust_drake.diagram import ClosedLoopConfig, build_closed_loop

    assert ClosedLoopConfig(robot="panda").resolved().rate == 1000.0
    assert ClosedLoopConfig(robot="d2r2").resolved().rate == 2500.0
    assert ClosedLoopConfig(robot="serial7").resolved().rate == 2500.0
    assert ClosedLoopConfig(robot="panda", rate=500.0).resolved().rate == 500.0
    loop = build_closed_loop(ClosedLoopConfig(robot="panda", controller="pd", trajectory="sine", duration=0.01))
    assert loop.period == 1e-3
