"""The one exception type raised by hdnet for bad input (shapes, specs, checkpoints, options)."""


class HdNetError(ValueError):
    """Bad input to hdnet: the message is one sentence naming the value and what is wrong with it."""
