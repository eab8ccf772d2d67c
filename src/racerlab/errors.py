"""Errors for user mistakes: each carries one line that names the file, the problem and the fix.

Internal bugs still raise ordinary exceptions; the command line prints `RacerlabError` messages
without a traceback.
"""


class RacerlabError(Exception):
    """A problem with the user's input (a file, a flag, a reward function)."""


class TrackError(RacerlabError, ValueError):
    """A track file or track name that cannot be used."""


class ConfigError(RacerlabError, ValueError):
    """A bad key or value in a model folder's JSON/TOML files."""


class RewardFunctionError(RacerlabError):
    """The user's reward function raised or returned something that is not a finite number."""


class RacerlabWarning(UserWarning):
    """Something left out of a user's input and carried on without (skipped files, dropped rows); the command line
    prints it as one line."""
