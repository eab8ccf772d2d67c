"""racerlab: a fast local training ground for AWS-DeepRacer-style racing cars."""

__version__ = "0.1.0"

import os as _os

# PyTorch's OpenMP threads spin while they wait for work. On a machine that other processes keep busy,
# a spinning thread holds a core the working one needs: a PPO step measured 46.8 ms with 2 threads
# against 3.8 ms once waiting threads sleep (load 10 on 2 cores). The setting is read when torch loads,
# so it is set here, before anything in racerlab imports torch; a value set by the user is kept.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _numba_cache_dir() -> None:
    """numba's compiled-kernel cache goes to the user's cache folder, not into the package's source tree (a git
    checkout's `src/racerlab/*/__pycache__`); a NUMBA_CACHE_DIR set by the user is kept. Set before numba loads."""
    if "NUMBA_CACHE_DIR" in _os.environ:
        return
    if _os.name == "nt":
        base = _os.environ.get("LOCALAPPDATA") or _os.path.expanduser("~\\AppData\\Local")
    elif _os.uname().sysname == "Darwin":
        base = _os.path.expanduser("~/Library/Caches")
    else:
        base = _os.environ.get("XDG_CACHE_HOME") or _os.path.expanduser("~/.cache")
    path = _os.path.join(base, "racerlab", "numba")
    try:
        _os.makedirs(path, exist_ok=True)
    except OSError:
        return  # numba then picks its own place, as before
    if _os.access(path, _os.W_OK):
        _os.environ["NUMBA_CACHE_DIR"] = path


_numba_cache_dir()

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
