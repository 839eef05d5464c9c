"""Exceptions raised for bad user input.

Every check on user input raises :class:`SwimInputError` (a ``ValueError``) with a message that names the
offending variable and the expected units or range, so that no traceback from deep inside the engine
reaches the user.
"""


class SwimInputError(ValueError):
    """Input (scene, time, observer, camera or option) is missing, malformed or out of range."""
