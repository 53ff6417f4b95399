"""Optional dependencies (pip extras) and the error that names the missing one.

The main path (simulate, demo, repair, the Drake ellipsoid backend) needs only the hard
dependencies. A few features need an extra:

- ``cvxpy``: the cvxpy ellipsoid backend and the ``direct`` backend (pip ``clarabel``), both
  cross-checks of the Drake ``MathematicalProgram`` solve;
- ``dask``: ``batch --scheduler`` / ``run_batch(scheduler=...)`` on a Dask cluster.

``pip install 'robust_drake[test]'`` includes both.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from robust_drake.errors import RobustDrakeError

__all__ = ["EXTRAS", "import_extra"]

#: extra name -> the modules it provides (pyproject.toml ``[project.optional-dependencies]``)
EXTRAS = {"cvxpy": ("cvxpy", "clarabel"), "dask": ("dask", "distributed")}


def import_extra(module: str, extra: str, feature: str) -> ModuleType:
    """Import ``module`` of the pip extra ``extra``; if it is missing, raise RobustDrakeError
    saying that ``feature`` needs that extra and how to install it."""
    if module not in EXTRAS.get(extra, ()):
        raise ValueError(f"{module!r} is not a module of the extra {extra!r}")
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise RobustDrakeError(
            f"{feature} needs the {extra!r} extra: pip install 'robust_drake[{extra}]' "
            f"({module} could not be imported: {exc})"
        ) from None
