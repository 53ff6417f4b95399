"""Packaging (issue 11 part 2): URDFs as package data, no backend switch on import, extras.

The wheel itself (its URDFs, an install into a fresh venv, ``simulate`` outside the checkout)
is checked by ``make wheel-check`` (.ci/wheel_check.sh), which needs the package index.
"""

import importlib.resources
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError

REPO = pathlib.Path(__file__).resolve().parents[1]

# Imports every module of the package under the backend the caller chose, then draws with the
# library's plotting functions; prints the backend before/after and pyplot's open figures.
_IMPORT_ALL = r"""
import importlib, json, pkgutil, sys
import matplotlib
if len(sys.argv) > 1:
    matplotlib.use(sys.argv[1])
import matplotlib.pyplot as plt     # what a notebook has loaded before it imports the library
before = matplotlib.get_backend()
import pandas as pd
import robust_drake
names = [m.name for m in pkgutil.walk_packages(robust_drake.__path__, "robust_drake.")]
for name in names:
    importlib.import_module(name)
after_import = matplotlib.get_backend()
from robust_drake.montecarlo import boxplot
df = pd.DataFrame({"controller": ["pd", "pd", "sp1"], "status": ["ok"] * 3,
                   "maxerr_task": [1e-3, 2e-3, 5e-4], "error_task": [1e-4, 2e-4, 1e-4]})
boxplot(df, "box.png")
print(json.dumps({"before": before, "after_import": after_import,
                  "after_plot": matplotlib.get_backend(), "modules": len(names),
                  "open_figures": plt.get_fignums()}))
"""


def _run(code, args=(), env_extra=None, cwd=None):
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in [env.get("PYTHONPATH")] if p])
    env.update(env_extra or {})
    out = subprocess.run([sys.executable, "-c", code, *args], env=env, cwd=cwd,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("how", ["inline", "svg"])
def test_import_and_plots_never_change_the_backend(tmp_path, how):
    """A notebook's inline backend (MPLBACKEND) or a backend chosen in code survives importing
    every module of robust_drake and drawing with its plot functions, which leave no pyplot
    figure behind and still write the file."""
    if how == "inline":
        pytest.importorskip("matplotlib_inline")
        r = _run(_IMPORT_ALL, env_extra={"MPLBACKEND": "module://matplotlib_inline.backend_inline"},
                 cwd=tmp_path)
        assert "inline" in r["before"]
    else:
        r = _run(_IMPORT_ALL, args=["svg"], cwd=tmp_path)
        assert r["before"] == "svg"
    assert r["modules"] > 30  # really walked the package
    assert r["after_import"] == r["before"]
    assert r["after_plot"] == r["before"]
    assert r["open_figures"] == []
    assert (tmp_path / "box.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_command_line_selects_agg_but_keeps_a_loaded_backend():
    """The CLI process uses the file backend Agg (even against MPLBACKEND); a session that has
    matplotlib loaded already (a notebook calling main()) keeps its backend."""
    code = r"""
import json, sys
pre = sys.argv[1] == "preloaded"
if pre:
    import matplotlib
    matplotlib.use("svg")
from robust_drake.cli import main
status = main(["simulate", "--robot", "no_such_robot"])   # a user error: returns 2 early
import matplotlib
print(json.dumps({"status": status, "backend": matplotlib.get_backend().lower()}))
"""
    fresh = _run(code, args=["fresh"], env_extra={"MPLBACKEND": "svg"})
    assert fresh == {"status": 2, "backend": "agg"}
    loaded = _run(code, args=["preloaded"])
    assert loaded == {"status": 2, "backend": "svg"}


def test_named_urdfs_are_package_data():
    """Every named robot/load resolves to a real file inside the package's ``robots`` folder
    (what a wheel installs), found through importlib.resources, not through the checkout."""
    from robust_drake.models import ROBOTS, models_dir, resolve_urdf

    pkg = pathlib.Path(os.fspath(importlib.resources.files("robust_drake").joinpath("robots")))
    assert models_dir().resolve() == pkg.resolve()
    seen = set()
    for name, spec in ROBOTS.items():
        for load in spec.loads:
            path = resolve_urdf(name, load)
            assert path.parent.resolve() == pkg.resolve() and path.is_file()
            assert path.read_text().lstrip().startswith("<?xml")
            seen.add(path.name)
    # nothing shipped that no robot uses, nothing used that is not shipped
    assert seen == {p.name for p in pkg.glob("*.urdf")}
    # pyproject ships exactly that folder (URDFs and their robot descriptions) as package data
    text = (REPO / "pyproject.toml").read_text()
    assert 'robust_drake = ["robots/*.urdf", "robots/*.yaml"]' in text
    assert {p.stem for p in pkg.glob("*.yaml")} == set(ROBOTS)  # one description per named robot


def test_top_level_models_is_the_packaged_folder():
    """The repository keeps ``models/`` (a symlink to robust_drake/robots): same files."""
    models = REPO / "models"
    if not models.exists():
        pytest.skip("not a checkout")
    assert models.is_dir()
    assert models.resolve() == (REPO / "robust_drake" / "robots").resolve()
    assert sorted(p.name for p in models.glob("*.urdf")) == sorted(
        p.name for p in (REPO / "robust_drake" / "robots").glob("*.urdf"))


def _tiny_model():
    from robust_drake.uncertainty.regression import UncertaintyModel

    co = np.zeros((1, 1, 1, 2))
    co[0, 0, 0, 1] = 1.0
    return UncertaintyModel(np.ones((1, 1, 1)), np.full((1, 1), 2.0), co, ["tau1"], np.array([1.0]))


@pytest.mark.parametrize("module, backend", [("cvxpy", "cvxpy"), ("clarabel", "direct")])
def test_missing_cvxpy_extra_is_named(monkeypatch, module, backend):
    from robust_drake.uncertainty.ellipsoid import solve_ellipsoid

    monkeypatch.setitem(sys.modules, module, None)  # as if not installed
    with pytest.raises(RobustDrakeError, match=r"needs the 'cvxpy' extra: pip install 'robust_drake\[cvxpy\]'"):
        solve_ellipsoid(_tiny_model(), formulation="full", backend=backend, certify_draws=0)


def test_missing_dask_extra_is_named(monkeypatch):
    from robust_drake.parallel import run_parallel

    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(RobustDrakeError, match=r"needs the 'dask' extra: pip install 'robust_drake\[dask\]'"):
        run_parallel(abs, [1, -2], scheduler="tcp://127.0.0.1:1")


def test_main_path_needs_no_extra(tmp_path):
    """Without cvxpy, clarabel, scs, dask and distributed importable, the default ellipsoid
    backend (Drake) and a closed-loop simulation still run."""
    code = r"""
import json, sys
for m in ("cvxpy", "clarabel", "scs", "dask", "distributed"):
    sys.modules[m] = None
import numpy as np
from robust_drake.uncertainty.ellipsoid import solve_ellipsoid
from robust_drake.uncertainty.regression import UncertaintyModel
from robust_drake.diagram import ClosedLoopConfig, simulate
co = np.zeros((1, 1, 1, 2)); co[0, 0, 0, 1] = 1.0
M = UncertaintyModel(np.ones((1, 1, 1)), np.full((1, 1), 2.0), co, ["tau1"], np.array([1.0]))
r = solve_ellipsoid(M, formulation="full", certify_draws=0)
res = simulate(ClosedLoopConfig(robot="d2r2", controller="pd", duration=0.02))
print(json.dumps({"center": float(r.theta0[0]), "P": float(r.P[0, 0]),
                  "e1": res.metrics["error1"]}))
"""
    r = _run(code, cwd=tmp_path)
    # x = 2 + delta, |delta| <= 1: the interval [1, 3], i.e. centre 2 and P = 1
    assert r["center"] == pytest.approx(2.0, abs=1e-4)
    assert r["P"] == pytest.approx(1.0, rel=1e-3)
    assert np.isfinite(r["e1"])
