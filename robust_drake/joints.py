"""How joints are named for a person: numbered from 1, with the URDF name beside the number.

One convention everywhere text or a file names a joint (messages, warnings, report.md,
report.json, effect labels ``spring[2]``, signal names ``q2``, figure labels, command-line
arguments): joint k is the k-th moving joint of the URDF in Drake's velocity order, k = 1..n,
the same k as the CSV columns ``q<k>``, ``tau<k>`` and ``SimulationResult.to_pandas``. Python
array indices stay 0-based (``q[:, j]`` is joint ``j + 1``); the functions here turn an index
into the text.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence


def joint_number(j: int) -> int:
    """The joint number (from 1) of the 0-based index ``j``."""
    return int(j) + 1


def joint_text(j: int | None, names: Sequence[str] | None = None) -> str:
    """``"joint 2 (shoulder_lift_joint)"`` for index 1 (``"all joints"`` for None); without
    ``names`` (or with too few) just ``"joint 2"``."""
    if j is None:
        return "all joints"
    j = int(j)
    if names is not None and 0 <= j < len(names):
        return f"joint {j + 1} ({names[j]})"
    return f"joint {j + 1}"


def joint_numbers(js: Iterable[int]) -> str:
    """``"1, 3"`` for the 0-based indices [0, 2]."""
    return ", ".join(str(int(j) + 1) for j in js)
