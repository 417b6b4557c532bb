"""The environment's construction errors."""

from expoctl.errors import InputError


class EnvArgumentError(InputError, ValueError):
    """A bad argument to the benchmark environment; the message starts with the argument's name. An InputError (the
    CLI prints it as is) and a ValueError (what gymnasium users catch)."""
