"""Tracks: loading AWS route files and racerlab's own tracks, geometry and arc-length projection.

    >>> from racerlab import track
    >>> t = track.load("lab_technical")          # a bundled track, a user track or a path
    >>> t.length, t.width, t.project([[0.0, 0.0]]).s
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from racerlab.track.core import Projection, Track, from_array, load_file
from racerlab.track.registry import DEFAULT_TRACK, names, resolve, user_dir

__all__ = ["DEFAULT_TRACK", "Projection", "Track", "from_array", "load", "load_file", "names", "user_dir"]


def load(name_or_path=DEFAULT_TRACK, reverse: bool = False) -> Track:
    """Load a track by name (bundled or in the user's folder) or by path; `reverse` drives it the other way."""
    if isinstance(name_or_path, Track):
        t = name_or_path
    else:
        path = resolve(name_or_path)
        t = _load_cached(str(path.resolve()), path.stat().st_mtime_ns)
    return t.reverse() if reverse else t


@lru_cache(maxsize=64)
def _load_cached(path: str, _mtime: int) -> Track:
    return load_file(Path(path))
