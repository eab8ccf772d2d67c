"""Atomic file writes: write to a hidden temporary name in the same folder, then rename.

A reader (or a training resumed after a crash) sees either the old file or the whole new one, never
half a file. Temporary names start with a dot and end with `.tmp-<pid>-<random>`, so the glob
patterns of the DeepRacer tools (`*-iteration.csv`, `TrainingMetrics*.json`) never match them;
`remove_stale_temps` deletes the ones a killed process left behind.
"""

from __future__ import annotations

import json
import os
import secrets
import tempfile
from pathlib import Path

from racerlab.errors import ConfigError
from racerlab.logs.files import kind_of
from racerlab.logs.scratch import sweep

TEMP_MARK = ".tmp-"
_swept: set[str] = set()  # folders this process has cleaned of dead writers' temporary files


def temp_path_for(path: str | os.PathLike) -> Path:
    """A fresh hidden temporary name next to `path` (same folder, so the rename is atomic). The first time a
    process writes in a folder, it removes the temporary files that killed writers left there."""
    path = Path(path)
    if str(path.parent) not in _swept:
        _swept.add(str(path.parent))
        remove_stale_temps(path.parent)
    return path.with_name(f".{path.name}{TEMP_MARK}{os.getpid()}-{secrets.token_hex(4)}")


def fsync_dir(folder: str | os.PathLike) -> None:
    """Make a rename in `folder` durable (a no-op where directories cannot be opened, e.g. Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def commit_temp(tmp: str | os.PathLike, path: str | os.PathLike, fsync: bool = True) -> Path:
    """Rename the finished temporary file `tmp` onto `path` (replacing it) and return `path`."""
    path = Path(path)
    os.replace(tmp, path)
    if fsync:
        fsync_dir(path.parent)
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes, fsync: bool = True) -> Path:
    """Write `data` to `path` atomically (parent folders are created); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path_for(path)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        return commit_temp(tmp, path, fsync)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if exc.filename is None:  # a failed write names no file: name the one being written
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | os.PathLike, text: str, fsync: bool = True) -> Path:
    """Write `text` (UTF-8) to `path` atomically; returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"), fsync)


def atomic_write_json(path: str | os.PathLike, obj, indent: int | None = None, fsync: bool = True) -> Path:
    """Write `obj` as JSON to `path` atomically (NaN and inf are refused: they are not JSON)."""
    return atomic_write_text(path, json.dumps(obj, indent=indent, allow_nan=False) + "\n", fsync)


def check_output(out: str | os.PathLike, flag: str, give: str) -> Path:
    """The file a command will write atomically at `out` (the value of its `flag`), resolved through links, once it
    is known that the write can happen and replaces at most a regular file you may write; one line naming `flag`,
    the problem and the fix (`give`: what to pass instead) otherwise. Nothing is written. What a command may
    replace besides (its own earlier output, a file it merges into) is the command's to check."""
    if str(out) in ("", "."):
        raise ConfigError(f"{flag} {str(out)!r}: no file name; give {give}")
    path = Path(os.path.realpath(out))
    if not path.parent.is_dir():
        raise ConfigError(f"{flag} {out}: the folder {path.parent} does not exist; create it or choose another file")
    try:  # what the atomic write will do: a new file in that folder
        tempfile.TemporaryFile(dir=path.parent).close()
    except OSError as exc:
        raise ConfigError(f"{flag} {out}: cannot write in {path.parent} ({exc.strerror}); choose a file in a writable "
                          "folder") from None
    if path.exists():
        if not path.is_file():
            what = "a folder" if path.is_dir() else kind_of(path.stat().st_mode)
            raise ConfigError(f"{flag} {out}: not a regular file ({what}); give {give}")
        if not os.access(path, os.W_OK):
            raise ConfigError(f"{flag} {out}: the file is read-only; make it writable or choose another file")
    return path


def remove_stale_temps(folder: str | os.PathLike) -> list[Path]:
    """Delete the temporary files left in `folder` by writers that are gone (killed); a live writer's stay."""
    return sweep(Path(folder), lambda name: name.startswith(".") and TEMP_MARK in name)
