"""SP1's boundary layer on arms without a published one (issue 14): the sampled-loop rule of
``spong.sampled_epsilon`` keeps the robust term of JS eq. 18 active on serial7 and the Siciliano
2-link arm, and the robust term measurably helps."""

import numpy as np
import pytest

from robust_drake.diagram import ClosedLoopConfig, _arm_for, build_closed_loop
from robust_drake.models import ROBOTS
from robust_drake.registry import BuildContext
from robust_drake.regressor import InverseDynamicsRegressor
from robust_drake.systems.controllers.spong import (SAMPLED_BETA, make_sp1, make_sp2, reference_regressor_norm,
                                                    reference_tube,
                                                    sampled_epsilon)

ROBOTS_UNDER_TEST = ["siciliano_2link", "serial7"]


def _heavier(plant, ctx, factor=1.15):
    """Every link 15 % heavier: inside SP1's default +-20 % box around the URDF parameters."""
    for k in range(1, 8):
        if plant.HasBodyNamed(f"link{k}"):
            b = plant.GetBodyByName(f"link{k}")
            b.SetMass(ctx, factor * b.default_mass())


def _run(robot, controller, **params):
    loop = build_closed_loop(ClosedLoopConfig(
        robot=robot, controller=controller, controller_params=params, trajectory="cpt", rate=2500.0,
        duration=1.0, observer="exact", plant_setup=[_heavier]))
    return loop.controller, loop.simulate()


def _robust_terms(robot, ctrl, res):
    """Along the logged run, recomputed from the states (JS eq. 11): ||u|| / rho of eq. 18, and
    per joint the RMS of the model-error torque Y theta~ and of what is left of it, Y (theta~ + u)
    (theta~ = theta0 - theta_true, theta_true the base parameters of the heavier plant)."""
    from robust_drake.models import make_plant
    from robust_drake.systems.controllers.spong import sp1_robust_input

    reg = InverseDynamicsRegressor.from_robot(robot)
    plant = make_plant(robot)
    pc = plant.CreateDefaultContext()
    _heavier(plant, pc)
    Lam = np.asarray(ctrl.Lambda)
    qt, qtd = res.q - res.q_d, res.v - res.qd_d
    Y = reg.slotine_li(res.q, res.v, res.qd_d - Lam * qt, res.qdd_d - Lam * qtd)
    xi = np.einsum("kip,ki->kp", Y, qtd + Lam * qt)
    u = np.array([sp1_robust_input(x, ctrl.rho, ctrl.epsilon) for x in xi])
    d0 = Y @ (ctrl.theta0 - reg.base_parameters(plant, pc))
    d1 = d0 + np.einsum("kip,kp->ki", Y, u)
    late = res.t > 0.2
    rms = lambda d: np.sqrt(np.mean(d[late] ** 2, axis=0))  # noqa: E731
    return np.linalg.norm(u, axis=1) / ctrl.rho, rms(d0), rms(d1)


@pytest.fixture(scope="module", params=ROBOTS_UNDER_TEST)
def runs(request):
    robot = request.param
    return robot, {name: _run(robot, c, **p) for name, c, p in
                   (("sp1", "sp1", {}), ("sp1_no_layer", "sp1", {"epsilon": 1e12}), ("pd", "pd", {}),
                    ("sp2", "sp2", {}), ("sp2_no_layer", "sp2", {"epsilon": 1e12}))}


def test_robust_term_is_active(runs):
    """With the rule's epsilon the robust input ||u|| reaches a stated fraction of rho on the run:
    10 % on the Siciliano arm (measured 23 %), 0.5 % on serial7 (measured 0.72 %: rho = ||b||_2
    bounds a ball around a 43-parameter box, far larger than the box in most directions); the
    former rule (epsilon = rho y_max^2 / min K: 48 and 1.3e5) would have kept it >= 50x lower (same run, a first-order estimate: ||xi|| / epsilon_old).
    It cancels most of the model-error torque Y theta~ (RMS after 0.2 s): >= 80 % on each Siciliano
    joint (measured 95 %), >= 30 % on serial7's joints 0-2 which carry it (measured 41-78 %),
    and >= 30 % over all joints together (measured 44 % on serial7)."""
    robot, r = runs
    ctrl, res = r["sp1"]
    assert not res.diverged
    frac, before, after = _robust_terms(robot, ctrl, res)
    stated = {"siciliano_2link": 0.1, "serial7": 0.005}[robot]
    assert frac.max() >= stated, (robot, frac.max())
    y_max = reference_regressor_norm(_ctx(robot), InverseDynamicsRegressor.from_robot(robot))
    eps_old = ctrl.rho * y_max ** 2 / np.min(ctrl.K)
    assert (frac * ctrl.epsilon / eps_old).max() < 0.02 * frac.max(), robot
    joints = {"siciliano_2link": [0, 1], "serial7": [0, 1, 2]}[robot]
    cut = {"siciliano_2link": 0.8, "serial7": 0.3}[robot]
    assert np.all(after[joints] <= (1 - cut) * before[joints]), (robot, before, after)
    assert np.linalg.norm(after) <= 0.7 * np.linalg.norm(before), (robot, before, after)


def test_sp1_beats_pd_and_its_own_law_without_the_robust_term(runs):
    """Same K, Lambda, theta0 and plant (15 % heavier than the URDF): SP1 with the rule's layer is
    5x better than PD in max error, and its RMS error below 0.6x that of SP1 with epsilon -> infinity
    (u -> 0, the nominal law; measured 0.06x on the Siciliano arm, 0.50x on serial7)."""
    robot, r = runs
    e = {k: np.abs(r[k][1].q - r[k][1].q_d) for k in ("sp1", "sp1_no_layer", "pd")}
    assert e["sp1"].max() < 0.2 * e["pd"].max(), (robot, e["sp1"].max(), e["pd"].max())
    rms = {k: float(np.sqrt(np.mean(x ** 2))) for k, x in e.items()}
    assert rms["sp1"] < 0.6 * rms["sp1_no_layer"], (robot, rms)


def test_sp2_with_the_split_layer_beats_pd_and_its_own_law_without_the_robust_term(runs):
    """SP2 (epsilon_i = epsilon rho_i / ||rho||): 5x better than PD in max error; RMS below SP2 with
    epsilon_i -> infinity (measured 0.13x on the Siciliano arm, 0.73x on serial7)."""
    robot, r = runs
    e = {k: np.abs(r[k][1].q - r[k][1].q_d) for k in ("sp2", "sp2_no_layer", "pd")}
    assert e["sp2"].max() < 0.2 * e["pd"].max(), robot
    rms = {k: float(np.sqrt(np.mean(x ** 2))) for k, x in e.items()}
    assert rms["sp2"] < {"siciliano_2link": 0.3, "serial7": 0.85}[robot] * rms["sp2_no_layer"], (robot, rms)


def test_measured_error_is_within_the_predicted_ultimate_bound(runs):
    """The per-joint bound of spong_ultimate_bound (Lyapunov, eq. 20) is not beaten by the run
    after its transient (0.5 s)."""
    robot, r = runs
    ctrl, res = r["sp1"]
    bound = np.asarray(ctrl.uncertainty["epsilon_rule"]["error_bound"])
    late = res.t > 0.5
    assert np.all(np.abs(res.q - res.q_d)[late].max(axis=0) <= bound), robot


def test_beyond_the_sampling_limit_the_torque_chatters():
    """The rule keeps h lambda_max(M^-1 (K + rho/eps Y Y^T)) <= beta = 0.5; the explicit-Euler
    limit is 2. At 8x smaller epsilon (beta ~ 4) the torque's total variation explodes (>100x),
    at the rule's epsilon it stays within 1.5x of PD's (Siciliano arm, 2500 Hz)."""
    robot = "siciliano_2link"
    ctrl, ok = _run(robot, "sp1")
    _, bad = _run(robot, "sp1", epsilon=ctrl.epsilon / 8)
    _, pd = _run(robot, "pd")
    tv = {k: float(np.sum(np.abs(np.diff(x.u, axis=0)))) for k, x in (("ok", ok), ("bad", bad), ("pd", pd))}
    assert tv["ok"] < 1.5 * tv["pd"] and tv["bad"] > 100 * tv["ok"], tv


def _ctx(robot, period=4e-4):
    c = ClosedLoopConfig(robot=robot, trajectory="cpt", rate=1.0 / period).resolved()
    n = ROBOTS[robot].n
    return BuildContext(robot=robot, arm=_arm_for(robot, n), load=c.load, n=n, period=period, config=c)


def test_sp2_splits_the_layer_with_the_same_budget():
    """SP2's epsilon_i = epsilon rho_i / ||rho||: sum rho_i epsilon_i = ||rho|| epsilon (same bound)."""
    ctx = _ctx("siciliano_2link")
    s1, s2 = make_sp1(ctx), make_sp2(ctx)
    rho_i, eps_i = np.asarray(s2.rho), np.asarray(s2.epsilon)
    assert np.isclose(np.sum(rho_i * eps_i), s1.rho * s1.epsilon, rtol=1e-12)
    tube = reference_tube(ctx, InverseDynamicsRegressor.from_robot("siciliano_2link"), s1.K)
    # the layer is proportional to the period (eq. of sampled_epsilon at K h << beta)
    assert np.isclose(sampled_epsilon(s1.rho, tube, 2e-4) / sampled_epsilon(s1.rho, tube, 4e-4), 0.5, rtol=0.02)
    assert SAMPLED_BETA < 2.0
