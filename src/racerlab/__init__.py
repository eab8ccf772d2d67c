"""racerlab: a fast local training ground for AWS-DeepRacer-style racing cars."""

__version__ = "0.1.0"

import os  # noqa: E402

# torch's OpenMP workers spin while they wait for work. Where the cores are shared (a laptop in use, several
# trainings, CI) the spinning threads starve the one doing the work: one PPO update measured 64 s instead of
# 1.6 s on a loaded 2-core machine, and `--minutes` overran by as much. Passive waiting costs little on an idle
# machine. It must be set before torch is imported; a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

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
