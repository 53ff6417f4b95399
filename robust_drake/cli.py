"""The ``robust-drake`` command line: one subcommand per job.

Each subcommand lives in its own module under :mod:`robust_drake.commands` and
exposes ``register(subparsers)``, which adds an ``argparse`` sub-parser and sets
``func=run`` on it. ``run(args)`` returns an exit status. Every subcommand has
``--json`` (one JSON document on stdout, nothing else) and a readable table
otherwise; ``--plot DIR`` where a picture helps: a folder, created if needed, into which the
command writes its named PNG files (the same meaning in every command).

Global options (before the subcommand, or after it): ``--version``, ``-v``/``--verbose``
(debug messages), ``-q``/``--quiet`` (no progress, warnings and errors only). Progress goes to
stderr (the ``robust_drake`` logger and progress bars); stdout holds only the result, so
``--json`` output stays one JSON document.

User errors (:class:`robust_drake.errors.RobustDrakeError`) are printed as
``error: ...`` on stderr with exit status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys

from robust_drake.errors import RobustDrakeError
from robust_drake.tables import format_table  # noqa: F401 - the subcommands' import

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
    "robust_drake.commands.epsilon_search",
    "robust_drake.commands.logs_to_control",
    "robust_drake.commands.list",
    "robust_drake.commands.control",
    "robust_drake.commands.excite",
]


#: The Examples section of each subcommand's ``--help`` (runtimes measured on a busy 2-core
#: machine with the command shown; BUILD_NOTES / handoff "ux" has the measurements).
EXAMPLES: dict[str, list[str]] = {
    "simulate": [
        "robust-drake simulate --robot d2r2 --load max --controller SP1 --trajectory cpt --json",
        "robust-drake simulate --controller sp2 --trajectory circle --plot out/circle_sp2",
        "robust-drake simulate --trajectory cpt --trajectory-param amplitude_deg=45 --duration 1",
        "robust-drake simulate --meshcat out/replay.html        # a 3-D replay to open in any browser",
        "robust-drake simulate --meshcat --meshcat-wait 60      # live viewer on localhost for 60 s",
        "robust-drake simulate --trajectory circle --animation out/arm.gif   # planar stick figure",
        "robust-drake simulate --diagram out/loop.svg           # block diagram (Graphviz)",
        "robust-drake simulate --robot panda --controller sp1 --trajectory sine --rate 1000",
        "robust-drake simulate --design out/sp1.yaml          # rerun a loop designed by control",
    ],
    "demo": ["robust-drake demo --out out                 # about {demo} on 2 cores",
             "robust-drake demo --out out --skip-repair   # only the CPT tables (JS tables 2-3)"],
    "bascetta": ["robust-drake bascetta --gains 25,5 --json",
                 "robust-drake bascetta --gains 100,10 --plot out/br"],
    "batch": ["robust-drake batch examples/batch_small.yaml --out out/batch_small.parquet   # rerun resumes",
              "robust-drake batch examples/batch_small.yaml --out out/b.parquet --scheduler tcp://host:8786"],
    "montecarlo": ["robust-drake montecarlo --robot d2r2 --controllers SP1,SP2,ZC,LG+ --draws 200   # 800 runs, "
                   "about {montecarlo}",
                   "robust-drake montecarlo --controllers sp1,sp2 --draws 20 --plot out/mc   # about a minute",
                   "robust-drake montecarlo --robot imi_scara --ellipsoid ellipsoid.json --controllers calafiore"],
    "compare": ["robust-drake compare --table 4 5 --plot out/js",
                "robust-drake compare --table 2 3 --controllers sp1,sp2 --json"],
    "sweep-rate": ["robust-drake sweep-rate --controllers sp1,sp2,zc --rates 250,500,1000,2500,5000 --plot out/rate"],
    "repair": ["robust-drake repair fit*.csv --robot dfki_double_pendulum_c1 --validate val*.csv --out out/repair_c1"
               "   # about {repair}",
               "robust-drake repair fit.csv --robot my_arm.urdf --out out/r --force --json > report.json",
               "robust-drake repair fit.csv --robot d2r2 --effects position_dependent,stribeck --out out/r"],
    "ellipsoid": ["robust-drake ellipsoid --samples 5 --json",
                  "robust-drake ellipsoid --samples 20 --save out/ellipsoid.json"],
    "calafiore": ["robust-drake calafiore --plot out/ci", "robust-drake calafiore --n-true 5 --json"],
    "epsilon-search": ["robust-drake epsilon-search --controllers sp1,sp2 --plot out/eps"],
    "logs-to-control": ["robust-drake logs-to-control --robot puma560_3link --plot out/ltc   # about {logs_to_control}",
                        "robust-drake logs-to-control --robot siciliano_2link --draws 20 --json"],
    "control": ["robust-drake control out/repair_c1/report.json --controller ci --plot out/ctl",
                "robust-drake control out/repair_c1/report.json --controller sp1 --design out/sp1.yaml --force"],
    "excite": ["robust-drake excite panda --duration 10 --out out/panda_excitation.csv --plot out/exc",
               "robust-drake excite dfki_double_pendulum_c1 --for-effects position_dependent --json"],
    "list": ["robust-drake list                       # everything, as tables",
             "robust-drake list controllers           # with their parameters and units",
             "robust-drake list --json | jq '.robots[].name'"],
}

#: measured wall times quoted in the examples (and README), filled into EXAMPLES
RUNTIMES = {"demo": "1 min", "montecarlo": "11 min on 2 cores", "repair": "17 s", "logs_to_control": "35 s"}


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, except that an ``examples:`` epilog keeps its lines as written."""

    def _fill_text(self, text, width, indent):
        if text.startswith("examples:"):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def _add_examples(name: str, parser: argparse.ArgumentParser) -> None:
    lines = EXAMPLES.get(name)
    if not lines:
        return
    parser.formatter_class = HelpFormatter
    body = "\n".join("  " + line.format(**RUNTIMES) for line in lines)
    parser.epilog = "examples:\n" + body + ("\n\n" + parser.epilog if parser.epilog and
                                              not parser.epilog.startswith("examples:") else "")


def add_output_flags(parser: argparse.ArgumentParser, plot: str | None = None, files: str | None = None) -> None:
    """Add the shared ``--json`` flag and, when ``plot`` is set, ``--plot DIR``.

    ``files`` names the PNG files the command writes into DIR (shown in ``--help``). ``plot``
    is kept truthy/None for compatibility: every ``--plot`` is a folder (see :func:`plot_dir`).
    """
    parser.add_argument("--json", action="store_true",
                        help="print one JSON document on stdout (progress, if any, goes to stderr)")
    if plot:
        what = f": {files}" if files else ""
        parser.add_argument("--plot", metavar="DIR", default=None,
                            help=f"write the figures as PNG files into folder DIR (created if needed){what}")


def plot_dir(args, option: str = "--plot") -> "pathlib.Path | None":
    """The ``--plot`` folder of ``args``, created; None when the option was not given.

    Refuses an empty value, an existing file, and a file name with an image suffix (``--plot``
    was a file in some commands before: the message says what it means now) with
    :class:`RobustDrakeError`."""
    import pathlib

    value = getattr(args, option.lstrip("-").replace("-", "_"), None)
    if value is None:
        return None
    if not str(value).strip():
        raise RobustDrakeError(f"{option} is empty; give a folder path (the PNG files are written into it)")
    path = pathlib.Path(value)
    if path.suffix.lower() in (".png", ".svg", ".pdf", ".jpg", ".jpeg") and not path.is_dir():
        raise RobustDrakeError(f"{option} takes a folder (the command writes its named PNG files into it), "
                               f"got the file name {value!r}; use e.g. {option} {path.parent / path.stem}")
    if path.exists() and not path.is_dir():
        raise RobustDrakeError(f"{option} {value}: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RobustDrakeError(f"{option} {value}: cannot create the folder ({exc.strerror})") from None
    return path


def show_progress(args) -> bool:
    """True unless ``-q`` was given: commands draw progress bars on stderr."""
    return getattr(args, "verbosity", 0) >= 0


def strict_json(obj):
    """``obj`` with numpy scalars/arrays as Python values, tuples as lists and every NaN or
    infinity as None, so that it serialises as strict JSON (RFC 8259 has no NaN)."""
    import math

    import numpy as np

    if isinstance(obj, dict):
        return {(k if isinstance(k, str) else str(k)): strict_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return strict_json(obj.tolist())
    if isinstance(obj, np.generic):
        return strict_json(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def print_json(obj) -> None:
    """Print ``obj`` as strict JSON (numpy converted, NaN/inf as null; ``allow_nan=False``
    so nothing non-standard can reach stdout)."""

    def default(o):
        raise TypeError(f"not JSON serialisable: {type(o).__name__}")

    text = json.dumps(strict_json(obj), default=default, indent=2, allow_nan=False)
    sys.stdout.write(text + "\n")


def non_negative(kind, option):
    """argparse type: a number >= 0 of ``kind`` (int or float); the message names ``option``."""
    import math

    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{option} must be a {'whole ' if kind is int else ''}number, "
                                             f"got {text!r}") from None
        if not (math.isfinite(value) and value >= 0):
            raise argparse.ArgumentTypeError(f"{option} must be >= 0, got {text}")
        return value

    parse.__name__ = kind.__name__
    return parse


def _version() -> str:
    from robust_drake import __version__

    return f"robust-drake {__version__}"


def _verbosity_flags(parser: argparse.ArgumentParser, default) -> None:
    g = parser.add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", dest="verbosity", action="store_const", const=1, default=default,
                   help="more messages: debug output of the robust_drake logger on stderr")
    g.add_argument("-q", "--quiet", dest="verbosity", action="store_const", const=-1, default=default,
                   help="no progress messages or bars; only warnings and errors on stderr")


def build_parser() -> argparse.ArgumentParser:
    """The ``robust-drake`` parser: global options and one sub-parser per command module."""
    parser = argparse.ArgumentParser(
        prog="robust-drake",
        description="Robust identification and robust control of robot manipulators, on Drake.",
        epilog="Run 'robust-drake COMMAND --help' for a command's options.",
    )
    parser.add_argument("--version", action="version", version=_version(),
                        help="print the package version and exit")
    _verbosity_flags(parser, default=0)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    for name, p in sub.choices.items():  # -v / -q also after the subcommand (SUPPRESS keeps a global one)
        _verbosity_flags(p, default=argparse.SUPPRESS)
        _add_examples(name, p)
    return parser


def configure_logging(verbosity: int) -> None:
    """Route the ``robust_drake`` logger to stderr at the level ``-v``/``-q`` chose
    (default INFO: progress messages shown)."""
    import logging

    from robust_drake.log import set_log_level

    set_log_level({1: logging.DEBUG, 0: logging.INFO, -1: logging.WARNING}[max(-1, min(1, verbosity))])


def glue_negative_values(parser, argv: list[str]) -> list[str]:
    """``--gains -25,5`` -> ``--gains=-25,5``: argparse takes a value that starts with '-' and is not a
    plain negative number (here a comma list) for an option and fails with "expected one argument".
    Only options that take a value are glued, so flags keep their meaning; nothing after ``--``."""
    import re

    takes_value = set()
    stack = [parser]
    while stack:
        p = stack.pop()
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                stack.extend(a.choices.values())
            elif a.option_strings and a.nargs != 0:
                takes_value.update(o for o in a.option_strings if o.startswith("--"))
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a == "--":
            out.extend(argv[i:])
            break
        if a in takes_value and i + 1 < len(argv) and re.match(r"^-[0-9.]", argv[i + 1]):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


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
    args = parser.parse_args(glue_negative_values(parser, sys.argv[1:] if argv is None else list(argv)))
    configure_logging(args.verbosity)
    from robust_drake.errors import set_caller

    token = set_caller("cli")  # messages name --force, --out (not overwrite=True, out=)
    import logging

    # the command's own handler prints the package's messages; pydrake installs a root handler the
    # first time Drake logs, after which every line appeared twice ("INFO:robust_drake:...")
    package_logger = logging.getLogger("robust_drake")
    propagate, package_logger.propagate = package_logger.propagate, False
    previous_term = _catch_sigterm()
    try:
        status = args.func(args)
    except RobustDrakeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Terminated:
        print("terminated", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except OSError as exc:
        message = disk_error_message(exc)
        if message is None:
            raise
        print(f"error: {message}", file=sys.stderr)
        return 2
    finally:
        from robust_drake.errors import _CALLER

        _CALLER.reset(token)
        package_logger.propagate = propagate
        if previous_term is not None:
            import signal

            signal.signal(signal.SIGTERM, previous_term)
    return int(status or 0)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread so that a command cleans up as after Ctrl-C (workers
    stopped, finished batch rows saved, temporary folders removed; no leaked semaphores)."""


def _catch_sigterm():
    """Turn SIGTERM into :class:`Terminated` while a command runs; returns the previous handler
    (None when not in the main thread, where signals cannot be set)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum, frame):
        raise Terminated()

    return signal.signal(signal.SIGTERM, handler)


def disk_error_message(exc: OSError) -> str | None:
    """One line for a write that failed for lack of room (ENOSPC: disk full; EFBIG: the file-size
    limit of ``ulimit -f``; EDQUOT: quota), naming the file; None for other OS errors."""
    import errno

    if exc.errno not in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
        return None
    where = f" writing {exc.filename}" if exc.filename else ""
    why = {errno.ENOSPC: "disk full", errno.EFBIG: "file too large for the file-size limit (ulimit -f)",
           errno.EDQUOT: "disk quota exceeded"}[exc.errno]
    return (f"{why}{where}: free some space (or raise the limit) and run again; an earlier result in the "
            "output place is left as it was")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
