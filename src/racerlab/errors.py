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


class ModelRefused(RacerlabError):
    """A trained model's checkpoint that racerlab will not use (`ModelFolder.open`, `racerlab.agent.inference_policy`):
    one line, `<checkpoint>: <problem>; <fix>`. `reason` says which cause refused it, for a reader that handles one
    of them itself (resume skips an unreadable or non-finite checkpoint for an older one); `problem` is the line's
    middle, without the path and the fix."""

    UNREADABLE = "unreadable"  # not a checkpoint racerlab can read: damaged, another format, more than data in it
    NONFINITE = "non-finite"  # NaN or infinite weights: the training diverged there
    METADATA = "metadata"  # trained with a model_metadata.json whose weights cannot carry over to the folder's
    NETWORK = "network"  # the weights do not fit the network built for the inputs it is used with

    def __init__(self, path, reason: str, problem: str, fix: str):
        super().__init__(f"{path}: {problem}; {fix}")
        self.path, self.reason, self.problem, self.fix = path, reason, problem, fix

    def __reduce__(self):  # one argument per field, so that it crosses process boundaries (a league's workers)
        return type(self), (self.path, self.reason, self.problem, self.fix)


class RacerlabWarning(UserWarning):
    """Something left out of a user's input and carried on without (skipped files, dropped rows); the command line
    prints it as one line."""
