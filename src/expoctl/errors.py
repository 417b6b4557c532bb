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
        self.problems = [(key, problem)]
        super().__init__(f"config key '{key}': {problem}")

    @classmethod
    def of(cls, problems: list[tuple[str, str]]) -> "ConfigError":
        """One error for every (key, problem) found in one pass: `key`/`problem` are the first's, the message
        names them all ("config key 'a': …; config key 'b': …")."""
        err = cls(*problems[0])
        err.problems = list(problems)
        err.args = ("; ".join(f"config key '{k}': {p}" for k, p in problems),)
        return err
