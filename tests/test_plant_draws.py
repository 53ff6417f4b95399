"""Plants drawn across a base-parameter ellipsoid are physically valid arms with the drawn
parameters (uncertainty.plant_draws)."""

import numpy as np

from robust_drake.uncertainty.plant_draws import draw_plants, make_physical, standard_for_base
from robust_drake.models import make_plant
from robust_drake.regressor import InverseDynamicsRegressor


def test_drawn_plants_have_the_drawn_parameters_and_are_valid_bodies():
    """A box-like ellipsoid of +-15 % on every base parameter of the C.1: Drake recomputes each
    drawn plant's base parameters equal to the draw (1e-8), the masses are the URDF's, every body
    passes Drake's own IsPhysicallyValid, and half the draws lie on the boundary."""
    reg = InverseDynamicsRegressor.from_robot("dfki_double_pendulum_c1")
    th0 = reg.base_parameters()
    P = np.diag((0.15 * np.abs(th0) + 1e-4) ** 2)
    draws, _ = draw_plants(reg, th0, P, 6, np.random.default_rng(3))
    plant = make_plant("dfki_double_pendulum_c1")
    for d in draws:
        ctx = plant.CreateDefaultContext()
        d.setup(plant, ctx)
        assert np.allclose(reg.base_parameters(plant, ctx), d.theta, rtol=1e-8, atol=1e-12)
        r = np.sqrt((d.theta - th0) @ np.linalg.solve(P, d.theta - th0))
        assert np.isclose(r, d.radius, rtol=1e-6)
        for name in ("link1", "link2"):
            b = plant.GetBodyByName(name)
            M = b.CalcSpatialInertiaInBodyFrame(ctx)
            assert M.IsPhysicallyValid() and np.isclose(M.get_mass(), b.default_mass())
    assert sum(d.kind == "boundary" for d in draws) == 3
    assert all(abs(d.radius - 1) < 1e-9 for d in draws if d.kind == "boundary")


def test_a_negative_rotor_inertia_or_a_body_without_central_inertia_is_refused():
    reg = InverseDynamicsRegressor.from_robot("dfki_double_pendulum_c1")
    th = reg.base_parameters().copy()
    names = list(reg.base_names)
    th_neg = th.copy()
    th_neg[names.index("Ia_joint2")] = -1e-3
    assert make_physical(reg, standard_for_base(reg, th_neg)) is None
    th_far = th.copy()  # first moment of link 2 ten times the URDF's at its Izz: Izz_c < 0
    th_far[names.index("mx_link2")] *= 10.0
    assert make_physical(reg, standard_for_base(reg, th_far)) is None
    assert make_physical(reg, standard_for_base(reg, th)) is not None
