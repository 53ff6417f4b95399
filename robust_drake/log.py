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
        super().emit(record)


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
