"""Logging for the library: one logger, ``"robust_drake"``, and progress callbacks.

Library functions report progress through a ``progress`` callback argument (a callable taking
one message string). Its default, None, means "send the message to the ``robust_drake`` logger
at INFO level": a program or notebook chooses what it sees with the standard :mod:`logging`
configuration (``logging.basicConfig(level=logging.INFO)``, or :func:`set_log_level`), and the
command line maps ``-v`` / ``-q`` onto it. Nothing here configures logging on import: like any
library, the package adds only a :class:`logging.NullHandler`.
"""

from __future__ import annotations

import logging
import sys
from typing import Callable, Optional, TextIO

LOGGER_NAME = "robust_drake"
logger = logging.getLogger(LOGGER_NAME)
logger.addHandler(logging.NullHandler())

Progress = Optional[Callable[[str], None]]

#: share of the total between two progress log lines off a terminal (piped, CI)
LOG_EVERY = 0.1


def get_logger(name: str | None = None) -> logging.Logger:
    """The package logger, or its child ``robust_drake.<name>``.

    Parameters
    ----------
    name : str, optional
        Dotted suffix of a child logger (e.g. ``"repair"``); None gives the package logger.

    Returns
    -------
    logging.Logger
        ``logging.getLogger("robust_drake")`` or ``logging.getLogger("robust_drake." + name)``.
    """
    return logger if not name else logger.getChild(name)


def progress_callback(progress: Progress = None, level: int = logging.INFO) -> Callable[[str], None]:
    """A one-argument message sink: ``progress`` itself, or the package logger when None.

    Parameters
    ----------
    progress : callable or None
        ``progress(message: str)``; None sends every message to the ``robust_drake`` logger.
    level : int
        Logging level of those messages when ``progress`` is None (default ``logging.INFO``).

    Returns
    -------
    callable
        A function of one string.
    """
    if progress is not None:
        return progress
    return lambda msg: logger.log(level, "%s", msg)


def set_log_level(level: int | str = "INFO", stream: TextIO | None = None) -> None:
    """Show the package's log messages at ``level`` and above on ``stream`` (default stderr).

    Adds (once) a plain ``message``-only handler to the ``robust_drake`` logger; calling it
    again only changes the level. For finer control use :mod:`logging` directly.

    Parameters
    ----------
    level : int or str
        A :mod:`logging` level (``logging.DEBUG``, ``"WARNING"``, ...).
    stream : file-like, optional
        Where the handler writes (default :data:`sys.stderr`, looked up at each message so
        that a redirected stderr is honoured).
    """
    if isinstance(level, str):
        levels = {"DEBUG": logging.DEBUG, "INFO": logging.INFO, "WARNING": logging.WARNING,
                  "ERROR": logging.ERROR, "CRITICAL": logging.CRITICAL}
        if level.upper() not in levels:
            from robust_drake.errors import RobustDrakeError

            raise RobustDrakeError(f"unknown log level {level!r}; use one of {', '.join(levels)}")
        level = levels[level.upper()]
    handler = next((h for h in logger.handlers if getattr(h, "_robust_drake", False)), None)
    if handler is None:
        handler = _StderrHandler(stream)
        handler._robust_drake = True
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
    else:
        handler.target = stream
    logger.setLevel(level)
    handler.setLevel(level)


class _StderrHandler(logging.StreamHandler):
    """A StreamHandler whose default stream is the *current* ``sys.stderr`` (pytest, notebooks
    and the command line's tests swap it)."""

    def __init__(self, stream=None):
        super().__init__(stream or sys.stderr)
        self.target = stream

    def emit(self, record):
        self.stream = self.target or sys.stderr
        if self.target is None and _root_prints(self.stream):
            return  # a console handler on the root logger (pydrake's configure_logging) prints it once
        try:  # through tqdm.write: an open progress bar is cleared, the line printed, the bar redrawn
            from tqdm import tqdm

            tqdm.write(self.format(record), file=self.stream)
        except Exception:  # noqa: BLE001 - logging never raises
            self.handleError(record)


def _root_prints(stream) -> bool:
    """True when a record propagated from the package logger is already printed on ``stream``
    by a console handler of the root logger (``logging.basicConfig``, pydrake's
    ``configure_logging``), so that our own handler would print it a second time."""
    if not logger.propagate:
        return False
    return any(isinstance(h, logging.StreamHandler) and not isinstance(h, logging.FileHandler)
               and getattr(h, "stream", None) in (stream, sys.stderr, sys.__stderr__)
               for h in logging.getLogger().handlers)


# --- progress: a bar on a terminal or in a notebook, a log line every ~10 % otherwise ----------


def in_notebook() -> bool:
    """True inside a Jupyter kernel (where tqdm draws a widget bar)."""
    ip = sys.modules.get("IPython")
    if ip is None:
        return False
    try:
        shell = ip.get_ipython()
    except Exception:  # noqa: BLE001
        return False
    return shell is not None and getattr(shell, "kernel", None) is not None


def interactive() -> bool:
    """True when a person watches: stderr is a terminal, or the code runs in a notebook."""
    return in_notebook() or bool(getattr(sys.stderr, "isatty", lambda: False)())


def _bars_wanted() -> bool:
    """Bars are drawn when someone watches and the package logger is not quietened
    (``set_log_level("WARNING")`` / ``-q`` turn them off)."""
    return interactive() and (logger.level == logging.NOTSET or logger.level <= logging.INFO)


#: the layout of a progress log line (tqdm's own meter formatter fills it in)
LOG_FORMAT = "{desc}: {percentage:3.0f}% ({n_fmt}/{total_fmt} {unit}), elapsed {elapsed}, remaining {remaining}"


class LogProgress:
    """The off-terminal twin of a tqdm bar: the same ``update`` / ``set_postfix`` / ``close``
    interface, writing one INFO line to the package logger each time another ``every`` share of
    ``total`` is done (and at the end), with the elapsed and the remaining time
    (:meth:`tqdm.tqdm.format_meter` formats it).

    Parameters
    ----------
    total : int
        Number of steps.
    desc : str
        What runs ("montecarlo", "repair").
    unit : str
        Name of a step, plural ("runs", "stages").
    every : float
        Share of ``total`` between two lines (default :data:`LOG_EVERY`, 10 %).
    level : int
        Logging level of the lines (default INFO).
    """

    def __init__(self, total: int, desc: str = "", unit: str = "steps", every: float = LOG_EVERY,
                 level: int = logging.INFO):
        import math
        import time

        self.total, self.desc, self.unit, self.level = int(total), desc, unit, level
        self.n = 0
        self.postfix = ""
        self._step = max(1, math.ceil(every * self.total)) if self.total > 0 else 1
        self._next = self._step
        self._t0 = time.perf_counter()
        self.disable = False

    def update(self, k: int = 1) -> None:
        self.n += k
        if self.n >= self._next or self.n >= self.total:
            self._emit()
            while self._next <= self.n:
                self._next += self._step

    def _emit(self) -> None:
        import time

        from tqdm import tqdm

        line = tqdm.format_meter(min(self.n, self.total), self.total, time.perf_counter() - self._t0,
                                 prefix=self.desc, unit=self.unit, bar_format=LOG_FORMAT)
        logger.log(self.level, "%s%s", line, f" [{self.postfix}]" if self.postfix else "")

    def set_postfix(self, refresh: bool = True, **kwargs) -> None:
        self.postfix = ", ".join(f"{k}={v}" for k, v in kwargs.items())

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.postfix = s

    def set_description(self, desc: str | None = None, refresh: bool = True) -> None:
        pass  # the line names the whole task; a stage's name is in its own message

    def close(self) -> None:
        pass

    def __enter__(self) -> "LogProgress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def progress_bar(total: int, desc: str, unit: str = "steps", enabled: bool = True):
    """A progress reporter for ``total`` steps: a tqdm bar on a terminal or in a notebook
    (``tqdm.auto``), else a :class:`LogProgress` (an INFO line every ~10 % with elapsed and
    remaining time: piped output, CI, log files).

    Parameters
    ----------
    total : int
        Number of steps.
    desc : str
        Label ("montecarlo").
    unit : str
        Plural name of a step ("runs").
    enabled : bool
        False: a disabled bar (nothing drawn, nothing logged).

    Returns
    -------
    tqdm.tqdm or LogProgress
        Both have ``update(k)``, ``set_postfix(**kw)``, ``set_description(s)``, ``close()`` and
        work as context managers.
    """
    if enabled and _bars_wanted():
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit=unit.rstrip("s") or unit, file=sys.stderr,
                    dynamic_ncols=True, smoothing=0.1, leave=False)
    if enabled:
        return LogProgress(total, desc, unit)
    from tqdm import tqdm

    return tqdm(total=total, disable=True)


class StageTimer:
    """Wrap a module of stage functions so that each call advances one progress bar (a tqdm bar
    on a terminal or in a notebook, an INFO line per stage otherwise) and logs its wall time at
    DEBUG (``-v``): ``S = StageTimer(stages_module, total=8, desc="repair")``; then
    ``S.fit_baseline(...)`` runs ``stages_module.fit_baseline(...)`` timed. The bar closes after
    ``total`` stages (or with :meth:`close`). ``enabled=False`` (a caller that routes the
    messages itself) keeps the timings and draws nothing.
    """

    def __init__(self, module, total: int, desc: str, enabled: bool = True):
        self._module, self._desc, self._total, self._enabled = module, desc, total, enabled
        self._bar = None
        self._done = 0

    def __getattr__(self, name):
        func = getattr(self._module, name)
        if not callable(func) or name.startswith("_"):
            return func

        def timed(*args, **kwargs):
            import time

            if self._bar is None:
                self._bar = progress_bar(self._total, self._desc, unit="stages", enabled=self._enabled)
            self._bar.set_description(f"{self._desc}: {name}")
            t0 = time.perf_counter()
            out = func(*args, **kwargs)
            logger.debug("%s stage %s: %.2f s", self._desc, name, time.perf_counter() - t0)
            self._done += 1
            self._bar.set_postfix_str(name)
            self._bar.update(1)
            if self._done >= self._total:
                self.close()
            return out

        return timed

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class slow_step:
    """Context manager: log ``message`` (INFO) only if the block is still running after
    ``after`` seconds, so quick runs and input errors found at once print nothing extra.

    Parameters
    ----------
    message : str
        What the block is doing ("simulating SP1 on the D2R2 ...").
    after : float
        Delay [s] before the message is logged.
    """

    def __init__(self, message: str, after: float = 1.0):
        self.message, self.after, self._timer = message, after, None

    def __enter__(self) -> "slow_step":
        import threading

        self._timer = threading.Timer(self.after, logger.info, args=("%s", self.message))
        self._timer.daemon = True
        self._timer.start()
        return self

    def __exit__(self, *exc) -> None:
        self._timer.cancel()


def debug_solve(what: str, result, seconds: float | None = None) -> None:
    """One DEBUG line (``-v``) about a ``MathematicalProgram`` solve: what was solved, the
    solver, its status, the optimal cost and (when given) the wall time [s]."""
    if not logger.isEnabledFor(logging.DEBUG):
        return
    try:
        name = result.get_solver_id().name()
        status = str(result.get_solution_result()).split(".")[-1]
        cost = result.get_optimal_cost()
    except Exception:  # noqa: BLE001 - a debug line never fails the solve
        return
    logger.debug("solve %s: %s %s, cost %.6g%s", what, name, status, cost,
                 "" if seconds is None else f", {seconds:.3f} s")
