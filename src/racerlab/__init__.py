"""racerlab: a fast local training ground for AWS-DeepRacer-style racing cars."""

__version__ = "0.1.0"

from racerlab.errors import ConfigError, RacerlabError, RewardFunctionError, TrackError  # noqa: E402

__all__ = ["ConfigError", "RacerlabError", "RewardFunctionError", "TrackError", "__version__"]


def _register_envs() -> None:
    try:
        import gymnasium
    except ImportError:  # pragma: no cover - gymnasium is a dependency
        return
    if "racerlab/DeepRacer-v0" not in gymnasium.registry:
        gymnasium.register(id="racerlab/DeepRacer-v0", entry_point="racerlab.sim.env:DeepRacerEnv",
                           vector_entry_point="racerlab.sim.env:DeepRacerVectorEnv")


_register_envs()
