"""The link's one error."""


class LinkError(RuntimeError):
    """The link or the vehicle did not do what the flight needs; the message says what."""
