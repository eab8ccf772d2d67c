"""racerlab: a fast local training ground for AWS-DeepRacer-style racing cars."""

__version__ = "0.1.0"

from racerlab.errors import ConfigError, RacerlabError, RewardFunctionError, TrackError  # noqa: E402

__all__ = ["ConfigError", "RacerlabError", "RewardFunctionError", "TrackError", "__version__"]
