"""Every shipped robot description is complete and agrees with its URDF, and its numbers are
the only copy: the closed loop uses the description's values, and no module writes the D2R2's
published numbers a second time (a duplicated number drifts; this catches it)."""

from __future__ import annotations

import io
import math
import pathlib
import tokenize

import numpy as np
import pytest

from robust_drake.description import FLEXIBILITY_KEYS, load_description, packaged_description
from robust_drake.robots_dir import packaged_models_dir

FILES = sorted(packaged_models_dir().glob("*.yaml"))
PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "robust_drake"


def _regressor_columns(key: str) -> int:
    """Number of parameters of the closed-form regressor ``key`` (evaluated, not declared)."""
    from robust_drake.regressor import d2r2_regressor, imi_scara_regressor

    z = np.zeros(2)
    if key == "d2r2":  # JS eq. 15
        return np.asarray(d2r2_regressor(z, z, z, z)).shape[-1]
    if key == "imi_scara":  # CI section 5
        return np.asarray(imi_scara_regressor(z, z, z)).shape[-1]
    raise AssertionError(f"closed_form_regressor {key!r}: add its regressor to this test")


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_description_is_complete_and_matches_its_urdf(path):
    from robust_drake.models import make_plant

    d = load_description(path)
    assert d.name == path.stem and d.urdf and d.loads.get("none") == d.urdf
    n = d.n
    for load, urdf in d.loads.items():  # every load variant exists and has the same joints
        assert (path.parent / urdf).is_file(), urdf
        assert make_plant(str(path.parent / urdf)).num_velocities() == n, load
    assert len(d.link_lengths) == n
    for vec in (d.torque_limits, d.friction_compensation_k_hat, d.controller_design.K,
                d.controller_design.Lambda):
        assert vec is None or len(vec) == n
    if d.plant_friction is not None:
        assert len(d.plant_friction["coulomb"]) == len(d.plant_friction["viscous"]) == n
    assert d.saturate <= (d.torque_limits is not None)  # saturating needs limits
    if d.parameter_sets or d.controller_design.rho_sp2 is not None:
        p = _regressor_columns(d.closed_form_regressor)
        assert all(len(v) == p for v in d.parameter_sets.values())
        assert d.controller_design.rho_sp2 is None or len(d.controller_design.rho_sp2) == p
    if d.flexibility is not None:
        assert set(d.flexibility) == set(FLEXIBILITY_KEYS)
        assert len(d.flexibility["rotor_inertia"]) == len(d.flexibility["drive_stiffness"]) == n
    if d.drive == "direct":
        assert d.gear_ratio == 1.0
    if d.torque_interface == "link_side":  # rotor and gears sit inside the maker's torque loop
        assert d.gear_ratio is None and d.rotor_inertia is None


def test_d2r2_parameter_sets_agree_with_its_urdfs_and_each_other():
    """JS tables 8, 9 are the URDFs' theta (eq. 14) to the tables' rounding; table 11 is their
    mean; table 10 (SP2) their half-difference; SP1's rho the norm of table 10 to 0.2 % (the
    paper prints 0.1062); eq. 93's maximum load turns table 8 into table 9."""
    from robust_drake.models import d2r2_theta_from_plant, make_plant
    from robust_drake.montecarlo import d2r2_theta_from_load

    d = packaged_description("d2r2")
    lo, hi, mid = (np.array(d.parameter_sets[k]) for k in ("unloaded", "loaded", "theta0"))
    for load, table in (("none", lo), ("max", hi)):
        np.testing.assert_allclose(d2r2_theta_from_plant(make_plant("d2r2", load)), table, atol=1e-3)
    np.testing.assert_allclose(mid, (lo + hi) / 2, atol=5e-4)
    np.testing.assert_allclose(d.controller_design.rho_sp2, (hi - lo) / 2, atol=5e-4)
    assert math.isclose(d.controller_design.rho_sp1, np.linalg.norm((hi - lo) / 2), rel_tol=2e-3)
    top = [d.load_intervals[k][1] for k in ("dm2", "dlc2", "dI2")]
    np.testing.assert_allclose(d2r2_theta_from_load(*top), hi, atol=1e-3)


def test_d2r2_closed_loop_uses_the_description():
    """The friction block of a default D2R2 loop produces F = -(F_v v + F_C sgn v) with the
    yaml's numbers; encoder and saturation defaults are the yaml's."""
    import yaml

    from robust_drake.diagram import ClosedLoop, ClosedLoopConfig

    raw = yaml.safe_load((packaged_models_dir() / "d2r2.yaml").read_text())
    pf = raw["simulation"]["plant_friction"]
    loop = ClosedLoop(ClosedLoopConfig(robot="d2r2", controller="pd", duration=0.01))
    (fr,) = [b for b in loop.effect_blocks if b.get_name() == "plant_friction"]
    ctx = fr.CreateDefaultContext()
    v = np.array([0.5, -2.0])
    fr.get_input_port(0).FixValue(ctx, np.concatenate([np.zeros(2), v]))
    expected = -(np.array(pf["viscous"]) * v + np.array(pf["coulomb"]) * np.sign(v))
    np.testing.assert_allclose(fr.get_output_port(0).Eval(ctx), expected, rtol=1e-15)
    c = loop.config  # the resolved config the loop was built from
    assert c.encoder_resolution == 2 * math.pi / raw["simulation"]["encoder_counts_per_rev"]
    assert c.torque_limit == raw["torque_limits"]


#: The D2R2's published numbers (and our friction choice) and a few of the other robots', each as
#: the token sequence a second copy in Python would have.  They live in robots/*.yaml only.
D2R2_NUMBERS = [
    ("655360",), ("655360.0",), ("1.2", ",", "2.3"), ("0.15", ",", "0.08"), ("31.2",), ("0.1062",),
    ("0.053", ",", "0.075"), ("0.678",), ("0.784",), ("0.731",), ("1.1841",), ("0.0694",),
    ("1.3254",), ("0.2571",), ("0.0276",), ("30.0", ",", "10.0"), ("50.0", ",", "20.0"),
    ("0.044566",), ("7.1e3",), ("5.0e4",),
    ("0.359",), ("4.69",),  # the IMI SCARA's l1 and theta0 (robots/imi_scara.yaml)
    ("97.6",), ("25.98",), ("6.07e-5",),  # PUMA torque limit and friction, AK80-6 rotor inertia
]


def _code_tokens(path: pathlib.Path) -> list[str]:
    """The code tokens of a module (comments and strings, docstrings included, dropped)."""
    skip = {tokenize.COMMENT, tokenize.STRING, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT,
            tokenize.DEDENT, tokenize.ENCODING}
    toks = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    return [t.string for t in toks if t.type not in skip]


def test_no_module_repeats_a_d2r2_number():
    hits = []
    for path in sorted(PACKAGE.rglob("*.py")):
        toks = _code_tokens(path)
        for seq in D2R2_NUMBERS:
            k = len(seq)
            if any(tuple(toks[i:i + k]) == seq for i in range(len(toks) - k + 1)):
                hits.append(f"{path.relative_to(PACKAGE)}: {' '.join(seq)}")
    assert hits == []


def test_the_number_scan_finds_a_copy(tmp_path):
    """The scan above is not blind: a module with one of the numbers is caught, a comment or a
    docstring with it is not."""
    bad = tmp_path / "bad.py"
    bad.write_text('"""Coulomb (1.2, 2.3) N m."""\n# 655360 counts\nCOULOMB = (1.2, 2.3)\n')
    toks = _code_tokens(bad)
    assert ("1.2", ",", "2.3") == tuple(toks[toks.index("1.2"):toks.index("1.2") + 3])
    assert "655360" not in toks
