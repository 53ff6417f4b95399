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


class OptionError(RobustDrakeError):
    """A bad value of a named option (a keyword of the Python API, a flag of the command line).

    The message is ``"<option> <text>"`` with the API's keyword; the command line prints the same
    text after its own flag (:meth:`as_flag`), so neither names the other's spelling."""

    def __init__(self, option: str, text: str):
        self.option, self.text = option, text
        super().__init__(f"{option} {text}")

    def as_flag(self, flag: str) -> str:
        return f"{flag} {self.text}"
