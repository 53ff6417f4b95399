"""User-facing errors.

Anything a user can cause with bad input (an unknown robot, a wrong CSV column, an
infeasible SDP, an unstable design) raises :class:`RobustDrakeError` with a message
that says what was wrong and what to do. The command line prints the message and
exits with status 2 instead of showing a traceback.
"""


class RobustDrakeError(ValueError):
    """An error caused by the user's input or by a design that cannot work."""


class SolverError(RobustDrakeError):
    """A convex program failed, was infeasible, or was solved too inaccurately to trust."""


class DataError(RobustDrakeError):
    """Measured data that cannot be used as given (missing columns, NaNs, units...)."""


# --- messages in the caller's words: "--force" on the command line, "overwrite=True" in Python ---
import contextvars as _contextvars

_CALLER = _contextvars.ContextVar("robust_drake_caller", default="python")


def set_caller(kind: str):
    """Mark the current context as called from ``"cli"`` or ``"python"`` (the command line sets
    ``"cli"``); returns the token for :meth:`contextvars.ContextVar.reset`."""
    return _CALLER.set(kind)


def option_name(cli: str, python: str) -> str:
    """The name of an option as the caller spells it: ``cli`` (``"--force"``) when the command
    line runs, else ``python`` (``"overwrite=True"``)."""
    return cli if _CALLER.get() == "cli" else python


def did_you_mean(word: str, choices, n: int = 3) -> str:
    """``" (did you mean 'sp1'?)"`` for the closest ``choices`` to ``word`` (difflib), or ``""``."""
    import difflib

    choices = [str(c) for c in choices]
    close = difflib.get_close_matches(str(word), choices, n=n, cutoff=0.6) or difflib.get_close_matches(
        str(word).lower(), [c.lower() for c in choices], n=n, cutoff=0.6)
    close = [next(c for c in choices if c.lower() == m.lower()) for m in close]
    close += [c for c in choices if len(str(word)) >= 2 and c.lower().startswith(str(word).lower()) and c not in close]
    if not close:
        return ""
    return " (did you mean " + " or ".join(repr(c) for c in close) + "?)"

class OptionError(RobustDrakeError):
    """A bad value of a named option (a keyword of the Python API, a flag of the command line).

    The message is ``"<option> <text>"`` with the API's keyword; the command line prints the same
    text after its own flag (:meth:`as_flag`), so neither names the other's spelling."""

    def __init__(self, option: str, text: str):
        self.option, self.text = option, text
        super().__init__(f"{option} {text}")

    def as_flag(self, flag: str) -> str:
        return f"{flag} {self.text}"
