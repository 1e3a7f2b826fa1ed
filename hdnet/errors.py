"""The one exception type raised by hdnet for bad input (shapes, specs, checkpoints, options).

It sits under hd's root error, ``hdcore.errors.HdError`` (documented there).
"""

from hdcore.errors import HdError


class HdNetError(HdError):
    """Bad input to hdnet: the message is one sentence naming the value and what is wrong with it."""
