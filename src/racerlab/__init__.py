"""racerlab: a fast local training ground for AWS-DeepRacer-style racing cars."""

__version__ = "0.1.0"

import os as _os

# PyTorch's OpenMP threads spin while they wait for work. On a machine that other processes keep busy,
# a spinning thread holds a core the working one needs: a PPO step measured 46.8 ms with 2 threads
# against 3.8 ms once waiting threads sleep (load 10 on 2 cores). The setting is read when torch loads,
# so it is set here, before anything in racerlab imports torch; a value set by the user is kept.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _compiled_sources_key(root: str | None = None) -> str:
    """A fingerprint of the package's numba-compiled sources. numba checks each cached kernel against its own file
    only, so a kernel that calls a compiled function of another file (the simulator's step calls the car's) kept
    the old code after that other file changed (a merged car refit ran with the car before it); a cache folder
    per fingerprint cannot. `root`: the package folder (default this one)."""
    import hashlib

    root = root or _os.path.dirname(_os.path.abspath(__file__))
    digest = hashlib.sha1()
    for folder, dirs, files in _os.walk(root):
        dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", "data"))
        for name in sorted(f for f in files if f.endswith(".py")):
            with open(_os.path.join(folder, name), "rb") as fh:
                text = fh.read()
            if b"numba" in text:
                digest.update(_os.path.relpath(_os.path.join(folder, name), root).encode() + b"\0" + text)
    return digest.hexdigest()[:16]


NUMBA_CACHE_KEEP_DAYS = 14  # cache folders of other sources unused this long are removed


def _prune_numba_caches(parent: str, keep: str) -> None:
    """Remove `parent`'s entries other than `keep` not touched for NUMBA_CACHE_KEEP_DAYS (older racerlabs' kernels;
    another checkout in use touches its own folder at each start)."""
    import shutil
    import time

    old = time.time() - NUMBA_CACHE_KEEP_DAYS * 86400
    try:
        entries = list(_os.scandir(parent))
    except OSError:
        return
    for entry in entries:
        try:
            if entry.name != keep and entry.stat(follow_symlinks=False).st_mtime < old:
                shutil.rmtree(entry.path) if entry.is_dir(follow_symlinks=False) else _os.remove(entry.path)
        except OSError:
            continue


def _numba_cache_dir() -> None:
    """numba's compiled-kernel cache goes to the user's cache folder, not into the package's source tree (a git
    checkout's `src/racerlab/*/__pycache__`), one folder per version of the compiled sources
    (`_compiled_sources_key`); a NUMBA_CACHE_DIR set by the user is kept. Set before numba loads."""
    if "NUMBA_CACHE_DIR" in _os.environ:
        return
    if _os.name == "nt":
        base = _os.environ.get("LOCALAPPDATA") or _os.path.expanduser("~\\AppData\\Local")
    elif _os.uname().sysname == "Darwin":
        base = _os.path.expanduser("~/Library/Caches")
    else:
        base = _os.environ.get("XDG_CACHE_HOME") or _os.path.expanduser("~/.cache")
    parent = _os.path.join(base, "racerlab", "numba")
    key = _compiled_sources_key()
    path = _os.path.join(parent, key)
    try:
        _os.makedirs(path, exist_ok=True)
        _os.utime(path)  # in use: not pruned by another version's start
    except OSError:
        return  # numba then picks its own place, as before
    if _os.access(path, _os.W_OK):
        _os.environ["NUMBA_CACHE_DIR"] = path
        _prune_numba_caches(parent, key)


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
