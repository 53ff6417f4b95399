"""robust_drake: robust identification and robust control of robot manipulators, on Drake.

Papers (text in ``../shared/seeds``):
- Calafiore & Indri, *Robust Calibration and Control of Robotic Manipulators*;
- Jaritz & Spong, *An Experimental Comparison of Robust Control Algorithms on a
  Direct Drive Manipulator*;
- Bascetta & Rocco, *Revising the robust control design for rigid robot manipulators*.

The flat API::

    import robust_drake as rd
    res = rd.simulate(controller="sp2", trajectory="circle", metrics_skip=1.0)
    res.metrics["maxerr_task"]            # m, JS eq. 59
    report = rd.repair(["fit.csv"], robot="d2r2", out="out/repair")   # RepairResult (report.json as a mapping)
    model = rd.identify(["fit.csv"], robot="d2r2")   # IdentifiedModel: rigid body + friction + set
    ell = rd.ellipsoid(samples=5)         # CI section 5.1 confidence ellipsoid

Importing the package is cheap and has no side effects: pydrake, numpy and matplotlib are
loaded only when a name below is first used (PEP 562 lazy attributes), and the matplotlib
backend is never changed. Progress messages go to the ``robust_drake`` logger
(:func:`set_log_level` shows them).
"""

from __future__ import annotations

import importlib

from robust_drake.errors import RobustDrakeError

__version__ = "0.1.0"

# public name -> module that defines it (loaded on first use)
_LAZY = {
    "simulate": "robust_drake.api",
    "build_closed_loop": "robust_drake.api",
    "make_plant": "robust_drake.api",
    "error_criteria": "robust_drake.api",
    "repair": "robust_drake.api",
    "identify": "robust_drake.api",
    "control": "robust_drake.api",
    "IdentifiedModel": "robust_drake.identification.model",
    "RepairResult": "robust_drake.model_repair.result",
    "ellipsoid": "robust_drake.api",
    "run_batch": "robust_drake.api",
    "run_montecarlo": "robust_drake.api",
    "default_gains": "robust_drake.api",
    "list_robots": "robust_drake.api",
    "list_controllers": "robust_drake.api",
    "list_trajectories": "robust_drake.api",
    "list_observers": "robust_drake.api",
    "excite": "robust_drake.api",
    "simulate_experiment": "robust_drake.api",
    "ExcitationConfig": "robust_drake.excitation.design",
    "ClosedLoopConfig": "robust_drake.diagram",
    "SimulationResult": "robust_drake.diagram",
    "DiscreteController": "robust_drake.systems.controllers.base",
    "tracking_figure": "robust_drake.plotting",
    "task_path_figure": "robust_drake.plotting",
    "repair_figure": "robust_drake.plotting",
    "render_diagram": "robust_drake.viz",
    "add_meshcat": "robust_drake.viz",
    "save_replay": "robust_drake.viz",
    "animate_planar": "robust_drake.viz",
    "save_animation": "robust_drake.viz",
    "set_log_level": "robust_drake.log",
    "get_logger": "robust_drake.log",
}

__all__ = ["RobustDrakeError", "__version__", *_LAZY]


def __getattr__(name: str):
    """Load a public name from its module on first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'robust_drake' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
