"""Where the robot files live: the shipped ``robust_drake/robots`` folder (URDFs and robot
descriptions, package data) and the folder in use (``ROBUST_DRAKE_MODELS`` overrides it).

A leaf module (imports nothing of robust_drake), so both :mod:`robust_drake.models` (the named
arms) and :mod:`robust_drake.description` (the per-robot descriptions) can depend on it without
depending on each other.
"""

from __future__ import annotations

import importlib.resources
import os
import pathlib

__all__ = ["MODELS_DIR", "models_dir", "packaged_models_dir"]


def _packaged_models_dir() -> pathlib.Path:
    """The URDF folder inside the installed package (``robust_drake/robots``).

    Package data of a regular (not zipped) install is a real folder, so the Traversable that
    ``importlib.resources`` returns is a path Drake's parser can open."""
    return pathlib.Path(os.fspath(importlib.resources.files("robust_drake").joinpath("robots")))


_DEFAULT_MODELS_DIR = _packaged_models_dir()
MODELS_DIR: pathlib.Path = pathlib.Path(os.environ.get("ROBUST_DRAKE_MODELS", _DEFAULT_MODELS_DIR))


def models_dir() -> pathlib.Path:
    """The models folder, re-reading ``ROBUST_DRAKE_MODELS`` at call time."""
    env = os.environ.get("ROBUST_DRAKE_MODELS")
    return pathlib.Path(env) if env else MODELS_DIR


def packaged_models_dir() -> pathlib.Path:
    """The shipped ``robust_drake/robots`` folder (URDFs and robot descriptions)."""
    return _DEFAULT_MODELS_DIR
