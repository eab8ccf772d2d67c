"""Where tracks come from: the bundled data files, the user's track folder and extra folders.

Search order for a name: a path to an existing file, the user's folders (so a user can shadow a
bundled track on purpose), then the bundled tracks.
"""

from __future__ import annotations

import difflib
import os
from pathlib import Path

from racerlab.errors import TrackError

BUNDLED_DIR = Path(__file__).resolve().parent.parent / "data" / "tracks"
DEFAULT_TRACK = "lab_technical"
TRACK_SUFFIXES = (".npy", ".csv")


def user_dir() -> Path:
    """The user's own track folder: $RACERLAB_HOME/tracks, default ~/.racerlab/tracks."""
    home = os.environ.get("RACERLAB_HOME")
    return (Path(home) if home else Path.home() / ".racerlab") / "tracks"


def search_dirs() -> list[Path]:
    """User folders first ($RACERLAB_TRACK_PATH entries, then the user folder), bundled last."""
    extra = [Path(p) for p in os.environ.get("RACERLAB_TRACK_PATH", "").split(os.pathsep) if p]
    return [*extra, user_dir(), BUNDLED_DIR]


def _files(folder: Path) -> dict[str, Path]:
    if not folder.is_dir():
        return {}
    out = {}
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() in TRACK_SUFFIXES and p.is_file():
            out.setdefault(p.stem, p)
    return out


def catalogue() -> dict[str, Path]:
    """Every known track name and the file it resolves to (earlier folders win)."""
    found: dict[str, Path] = {}
    for folder in search_dirs():
        for name, path in _files(folder).items():
            found.setdefault(name, path)
    return found


def names() -> list[str]:
    return sorted(catalogue())


def is_bundled(path: Path) -> bool:
    return path.resolve().parent == BUNDLED_DIR


def resolve(name_or_path) -> Path:
    """The file for a track name or path; a clear error with close matches when unknown.

    A bare file name that is not in the current folder (`reInvent2019_track.npy`) is looked up by its
    name in the track folders; an AWS track not downloaded yet says which command fetches it."""
    from racerlab.track.aws import fetch_hint

    p = Path(name_or_path)
    if p.suffix.lower() in TRACK_SUFFIXES or os.sep in str(name_or_path) or p.is_file():
        if p.is_file():
            return p
        if p.parent == Path(".") and p.stem in (cat := catalogue()):
            return cat[p.stem]
        hint = fetch_hint(p.name) if p.parent == Path(".") else None
        raise TrackError(f"{p}: no such track file" + (f"; {hint}" if hint else ""))
    cat = catalogue()
    if str(name_or_path) in cat:
        return cat[str(name_or_path)]
    hint = fetch_hint(str(name_or_path))
    if hint:
        raise TrackError(hint)
    close = difflib.get_close_matches(str(name_or_path), list(cat), n=3, cutoff=0.5)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    raise TrackError(f"unknown track {name_or_path!r}: not a file and not in {', '.join(map(str, search_dirs()))}."
                     f"{hint} Run `racerlab tracks list` to see the names, `racerlab tracks fetch --list` "
                     f"for the AWS tracks.")
