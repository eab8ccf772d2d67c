"""racerlab: a fast local training ground for AWS-DeepRacer-style racing cars."""

__version__ = "0.1.0"

import os as _os

# PyTorch's OpenMP threads spin while they wait for work. On a machine that other processes keep busy,
# a spinning thread holds a core the working one needs: a PPO step measured 46.8 ms with 2 threads
# against 3.8 ms once waiting threads sleep (load 10 on 2 cores). The setting is read when torch loads,
# so it is set here, before anything in racerlab imports torch; a value set by the user is kept.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


from racerlab import kernelcache as _kernelcache  # noqa: E402 - sets numba's cache before numba loads

_kernelcache.configure()

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
