"""The ``robust-drake`` command line: one subcommand per job.

Each subcommand lives in its own module under :mod:`robust_drake.commands` and
exposes ``register(subparsers)``, which adds an ``argparse`` sub-parser and sets
``func=run`` on it. ``run(args)`` returns an exit status. Every subcommand has
``--json`` (one JSON document on stdout, nothing else) and a readable table
otherwise; ``--plot`` where a picture helps.

User errors (:class:`robust_drake.errors.RobustDrakeError`) are printed as
``error: ...`` on stderr with exit status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys

from robust_drake.errors import RobustDrakeError

# Order = order in ``robust-drake --help``. A module listed here must exist.
COMMAND_MODULES = [
    "robust_drake.commands.simulate",
    "robust_drake.commands.demo",
    "robust_drake.commands.bascetta",
    "robust_drake.commands.batch",
    "robust_drake.commands.montecarlo",
    "robust_drake.commands.compare",
    "robust_drake.commands.sweep_rate",
    "robust_drake.commands.repair",
    "robust_drake.commands.ellipsoid",
    "robust_drake.commands.calafiore",
]


def add_output_flags(parser: argparse.ArgumentParser, plot: str | None = "FILE") -> None:
    """Add the shared ``--json`` flag and, when ``plot`` is a metavar, ``--plot``."""
    parser.add_argument("--json", action="store_true", help="print one JSON document for machines")
    if plot:
        parser.add_argument("--plot", metavar=plot, default=None, help="write plot(s) to this path")


def print_json(obj) -> None:
    """Print ``obj`` as JSON, converting numpy scalars/arrays."""
    import numpy as np

    def default(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
        raise TypeError(f"not JSON serialisable: {type(o).__name__}")

    json.dump(obj, sys.stdout, default=default, indent=2)
    sys.stdout.write("\n")


def format_table(rows: list[list], header: list[str], floatfmt: str = "{:.4g}") -> str:
    """A plain fixed-width text table (no extra dependency)."""
    cells = [[(floatfmt.format(c) if isinstance(c, float) else str(c)) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(header)]
    line = "  ".join(h.rjust(w) for h, w in zip(header, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells]
    return "\n".join([line, sep, *body])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="robust-drake",
        description="Robust identification and robust control of robot manipulators, on Drake.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    # Before numpy loads (the command modules import it lazily): single-threaded BLAS is far
    # faster for this package's many small solves; set OPENBLAS_NUM_THREADS to override.
    import os

    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    # The command line writes figures to files only, so its process uses the file backend Agg
    # (read when matplotlib first loads; worker processes inherit it). The library never picks a
    # backend; a session that already loaded matplotlib (a notebook calling main()) keeps its own.
    if "matplotlib" not in sys.modules:
        os.environ["MPLBACKEND"] = "Agg"
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        status = args.func(args)
    except RobustDrakeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return int(status or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
