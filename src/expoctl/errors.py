"""User-facing errors.

Anything a user can cause (a bad file, a bad config value, a corrupt image) raises `InputError`
with a message that names the file / row / key and what is wrong. Entry points (CLI, DVC stages)
catch it, print the message and exit non-zero — no traceback, no partial output.
"""


class InputError(Exception):
    """Bad input from the user: the message is complete and is shown as is."""


class ConfigError(InputError):
    """A configuration value is missing or invalid; the message names the dotted key."""

    def __init__(self, key: str, problem: str):
        self.key = key
        self.problem = problem
        super().__init__(f"config key '{key}': {problem}")
