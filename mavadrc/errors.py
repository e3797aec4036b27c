"""The errors the commands tell apart: a user's mistake (exit 2, nothing flown or run), a
flight that could not start or go on and a link that failed it (exit 1)."""


class UsageError(ValueError):
    """A mission or an option that cannot be flown or run as given (exit 2, nothing sent)."""


class FlightError(RuntimeError):
    """The flight could not start or go on; the message says why, in the vehicle's words."""


class LinkError(RuntimeError):
    """The link or the vehicle did not do what the flight needs; the message says what."""


def os_error_text(exc):
    """An OSError as a command says it: "PATH: reason" where it names a file, else its text."""
    if exc.filename and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return str(exc)
