"""User systems in the loop: ``ClosedLoopConfig(controller=..., observer=...)`` accepts a
LeafSystem instance or a factory ``f(ctx) -> LeafSystem`` with the contract's ports."""

import numpy as np
import pytest
from pydrake.multibody.tree import MultibodyForces
from pydrake.systems.framework import LeafSystem

from robust_drake.diagram import ClosedLoopConfig, build_closed_loop, simulate
from robust_drake.errors import RobustDrakeError
from robust_drake.models import make_plant
from robust_drake.systems.controllers.base import DiscreteController
from robust_drake.systems.controllers.spong import default_gains

ROBOT = "siciliano_2link"  # vertical 2R arm: gravity and coupling that PD does not model
SINE = dict(robot=ROBOT, trajectory="sine", rate=1000.0, observer="exact", duration=0.8)


class ComputedTorque(DiscreteController):
    """PD with Spong's gains plus Drake's inverse dynamics: u = M a_r + C v + g - K r,
    a_r = qdd_d - Lambda (qd - qd_d), r = (qd - qd_d) + Lambda (q - q_d)."""

    def __init__(self, ctx, K, Lambda):
        super().__init__(ctx.n, ctx.period, name="ComputedTorque")
        self.K, self.Lam = np.asarray(K, float), np.asarray(Lambda, float)
        self.plant = make_plant(ctx.robot, ctx.load)
        self.pctx, self.f0 = self.plant.CreateDefaultContext(), MultibodyForces(self.plant)

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        self.plant.SetPositions(self.pctx, q)
        self.plant.SetVelocities(self.pctx, v)
        a_r = qdd_d - self.Lam * v_error
        tau = self.plant.CalcInverseDynamics(self.pctx, a_r, self.f0)
        tau -= self.plant.CalcGravityGeneralizedForces(self.pctx)
        return tau - self.K * (v_error + self.Lam * (q - q_d))


def _ct_factory(ctx):
    return ComputedTorque(ctx, *default_gains(ctx))


def _max_error_after(res, t0=0.5):
    k = res.t >= t0
    return float(np.max(np.abs(res.q[k] - res.q_d[k])))


def test_custom_controller_factory_tracks_better_than_pd():
    ct = simulate(ClosedLoopConfig(controller=_ct_factory, **SINE))
    pd = simulate(ClosedLoopConfig(controller="pd", **SINE))  # same K, Lambda (default_gains)
    assert not ct.diverged and not pd.diverged
    e_ct, e_pd = _max_error_after(ct), _max_error_after(pd)
    # the model terms remove the gravity/inertia error that PD leaves: at least 10x smaller
    assert e_ct < 0.1 * e_pd, (e_ct, e_pd)
    assert ct.config["controller"] == "custom:_ct_factory"


def test_custom_controller_instance_equals_factory_and_is_single_use():
    loop = build_closed_loop(ClosedLoopConfig(controller=_ct_factory, **SINE))
    ctx = loop.build_context
    inst = ComputedTorque(ctx, *default_gains(ctx))
    cfg = ClosedLoopConfig(controller=inst, **SINE)
    r_inst = simulate(cfg)
    r_fac = loop.simulate()
    np.testing.assert_allclose(r_inst.u, r_fac.u, rtol=0, atol=1e-9)
    assert r_inst.config["controller"] == "custom:ComputedTorque"
    with pytest.raises(RobustDrakeError, match="already part of a closed loop"):
        build_closed_loop(cfg)


class _BadController(LeafSystem):
    def __init__(self, n, skip="v_error", size_q=None):
        super().__init__()
        for name, size in (("x_d", 3 * n), ("q", size_q or n), ("v", n), ("v_error", n)):
            if name != skip:
                self.DeclareVectorInputPort(name, size)
        self.DeclareVectorOutputPort("u", n, lambda c, o: o.SetFromVector(np.zeros(n)))


class _BadObserver(LeafSystem):
    def __init__(self, ctx):
        super().__init__()
        self.DeclareVectorInputPort("q", ctx.n)
        self.DeclareVectorInputPort("x_d", 3 * ctx.n)
        self.DeclareVectorOutputPort("v", ctx.n, lambda c, o: o.SetFromVector(np.zeros(ctx.n)))


def test_port_check_names_missing_or_wrong_port():
    with pytest.raises(RobustDrakeError, match="no input port 'v_error'"):
        build_closed_loop(ClosedLoopConfig(controller=_BadController(2), **SINE))
    with pytest.raises(RobustDrakeError, match="input port 'q' must be a vector of size 2"):
        build_closed_loop(ClosedLoopConfig(controller=lambda ctx: _BadController(ctx.n, skip=None, size_q=3), **SINE))
    with pytest.raises(RobustDrakeError, match="observer custom:_BadObserver has no output port 'v_error'"):
        build_closed_loop(ClosedLoopConfig(**dict(SINE, controller="pd", observer=_BadObserver)))
    with pytest.raises(RobustDrakeError, match="not a pydrake System"):
        build_closed_loop(ClosedLoopConfig(controller=lambda ctx: 3.0, **SINE))
    with pytest.raises(RobustDrakeError, match="controller must be a registry name"):
        ClosedLoopConfig(controller=3.0, **SINE)


class EulerObserver(LeafSystem):
    """Backward difference (q_k - q_{k-1}) / T for v and for the error (JS eq. 60)."""

    def __init__(self, ctx):
        super().__init__()
        n, self.T = ctx.n, ctx.period
        self.q_in, self.xd_in = self.DeclareVectorInputPort("q", n), self.DeclareVectorInputPort("x_d", 3 * n)
        self.h = self.DeclareDiscreteState(2 * n)  # previous q, previous q - q_d
        self.DeclarePeriodicDiscreteUpdateEvent(ctx.period, 0.0, self._push)
        self.DeclareVectorOutputPort("v", n, lambda c, o: o.SetFromVector(self._diff(c)[0]))
        self.DeclareVectorOutputPort("v_error", n, lambda c, o: o.SetFromVector(self._diff(c)[1]))

    def _now(self, c):
        q, xd = self.q_in.Eval(c), self.xd_in.Eval(c)
        return np.concatenate([q, q - xd[:len(q)]])

    def _diff(self, c):
        d = (self._now(c) - c.get_discrete_state(self.h).get_value()) / self.T
        return np.split(d, 2)

    def _push(self, c, s):
        s.get_mutable_vector(self.h).SetFromVector(self._now(c))

    def set_initial(self, c, q0, q_d0, qd_d0):  # arm at rest before t = 0, reference moving
        c.SetDiscreteState(self.h, np.concatenate([q0, q0 - q_d0 + self.T * qd_d0]))


def test_custom_observer_factory_matches_registry_euler():
    """The user's backward-difference observer gives the same loop as the registry's JS eq. 60
    estimator (encoder quantisation on, so the estimate is what the controller sees)."""
    base = dict(SINE, observer=None, encoder_resolution=2 * np.pi / 2 ** 16, duration=0.3)
    mine = simulate(ClosedLoopConfig(**dict(base, observer=EulerObserver), controller="sp1"))
    ref = simulate(ClosedLoopConfig(**dict(base, observer="euler"), controller="sp1"))
    assert mine.config["observer"] == "custom:EulerObserver"
    np.testing.assert_allclose(mine.q, ref.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(mine.u, ref.u, rtol=1e-9, atol=1e-6)
