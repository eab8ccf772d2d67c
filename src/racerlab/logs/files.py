"""Opening the files of a log folder: the one check every reader of logs goes through.

A log folder is data from anyone. A FIFO named like a simtrace blocks a read for ever, a device or a link to
`/dev/zero` is read without end, a gzip of a few megabytes may expand to gigabytes. So every file a reader opens
(`racerlab.logs` sources and metrics, the report's side files, calibrate's logs) is opened here: only regular files
(links followed), each at most `MAX_LOG_BYTES` long, decompressed ones too. A path a user gives that is none is one
line (`check_path`); an entry inside a folder that is none is skipped, and the folder's readers say so in one line
(`SkippedFiles`).
"""

from __future__ import annotations

import os
import stat
import warnings
import zlib
from pathlib import Path

from racerlab.errors import RacerlabError, RacerlabWarning

# The most racerlab reads from one log file, plain or decompressed: a 1 M-step simtrace is about 130 MB, and a file
# costs about three times its size in memory while it is parsed.
MAX_LOG_BYTES = 2 << 30
_CHUNK = 1 << 20


class LogFileError(RacerlabError, ValueError):
    """A log or metrics file that cannot be read (the message names the file and, where known, the line)."""


def kind_of(mode: int) -> str | None:
    """What a file of `mode` is when it is neither a regular file nor a folder (None when it is one of those)."""
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    if stat.S_ISFIFO(mode):
        return "a pipe (FIFO)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "a socket" if stat.S_ISSOCK(mode) else "not a regular file"


def special(path) -> str | None:
    """What `path` is when it exists and is neither a regular file nor a folder, links followed (a dangling link:
    "a broken link"); None otherwise."""
    try:
        return kind_of(os.stat(path).st_mode)
    except FileNotFoundError:
        return "a broken link" if os.path.islink(path) else None
    except OSError as exc:
        return f"not readable ({exc.strerror})"


def check_path(path, what: str = "a log folder or file") -> os.stat_result:
    """The stat of a path a user gives, once it is known to be a folder or a regular file (links followed); one line
    naming it and what to give otherwise."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise LogFileError(f"{path}: no such file or folder; give {what}") from None
    except OSError as exc:  # a link loop, a folder it may not enter
        raise LogFileError(f"{path}: cannot be opened ({exc.strerror}); give {what}") from None
    kind = kind_of(st.st_mode)
    if kind:
        raise LogFileError(f"{path}: not a file or a folder ({kind}); give {what}")
    return st


def open_regular(path, name: str | None = None):
    """The regular file `path` (links followed) opened for reading in binary; anything else is a one-line
    `LogFileError` naming it as `name`. Opened without blocking, so that a FIFO is refused, not waited on."""
    name = name or str(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise LogFileError(f"{name}: cannot be opened ({exc.strerror})") from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = "a folder" if stat.S_ISDIR(mode) else kind_of(mode)
        raise LogFileError(f"{name}: {kind}, not a file; racerlab reads only regular files")
    return os.fdopen(fd, "rb")


def read_bytes(path, name: str | None = None, limit: int | None = None) -> bytes:
    """The bytes of the regular file `path` (`open_regular`), at most `limit` (default `MAX_LOG_BYTES`); a longer
    file is a one-line `LogFileError` naming it as `name`."""
    limit = MAX_LOG_BYTES if limit is None else limit
    name = name or str(path)
    with open_regular(path, name) as f:
        size = os.fstat(f.fileno()).st_size
        if size > limit:
            raise _too_big(name, limit, "is")
        data = f.read(size + 1 if size else limit + 1)  # one buffer of the file's size, not of the limit
        if size and len(data) > size:  # it grew while being read
            data += f.read(limit + 1 - len(data))
    if len(data) > limit:
        raise _too_big(name, limit, "is")
    return data


def gunzip(data: bytes, name: str, limit: int | None = None, *, torn_ends: bool = False) -> bytes:
    """`data` decompressed (gzip; members one after another, as `gzip` writes appended files, and trailing zeros
    allowed), at most `limit` bytes (default `MAX_LOG_BYTES`); one that expands past the limit is a one-line
    `LogFileError`, and so is a damaged or cut member, unless `torn_ends`: then the whole members before it are the
    text (a file appended to by a process that crashed)."""
    limit = MAX_LOG_BYTES if limit is None else limit
    parts, size, rest = [], 0, data
    while rest:
        d = zlib.decompressobj(16 + zlib.MAX_WBITS)
        try:
            chunk = d.decompress(rest, limit + 1 - size)
        except zlib.error as exc:
            if torn_ends:
                break
            raise LogFileError(f"{name}: not a readable gzip file ({exc})") from None
        size += len(chunk)
        if size > limit or d.unconsumed_tail:
            raise _too_big(name, limit, "expands to")
        if not d.eof:
            if torn_ends:
                break
            raise LogFileError(f"{name}: not a readable gzip file (cut short: the download or the copy is "
                               "incomplete)")
        parts.append(chunk)
        rest = d.unused_data.lstrip(b"\0")
    return parts[0] if len(parts) == 1 else b"".join(parts)


def read_log(path, name: str | None = None) -> bytes:
    """A log file's text as bytes: `read_bytes`, decompressed when its name ends in `.gz`."""
    name = name or str(path)
    data = read_bytes(path, name)
    return gunzip(data, name) if name.endswith(".gz") else data


def _too_big(name: str, limit: int, verb: str) -> LogFileError:
    return LogFileError(f"{name}: {verb} more than {limit / 2**30:g} GiB, more than racerlab reads from one log file; "
                        "split it, or give the folder of the training's per-iteration files")


class SkippedFilesWarning(RacerlabWarning):
    """Entries of a log folder that are no regular files (pipes, devices, sockets, broken links), left out."""


class SkippedFiles:
    """The entries a folder walk leaves out because they are no regular files; `warn()` says so in one line."""

    def __init__(self, root) -> None:
        self.root = Path(root)
        self.found: list[tuple[str, str]] = []  # (relative path, what it is)

    def add(self, rel: str, kind: str) -> None:
        self.found.append((rel, kind))

    def __str__(self) -> str:
        n = len(self.found)
        shown = ", ".join(f"{rel} ({kind})" for rel, kind in self.found[:3]) + (", ..." if n > 3 else "")
        return (f"skipped {n} entr{'y' if n == 1 else 'ies'} that {'is' if n == 1 else 'are'} not a regular file: "
                f"{shown}; racerlab reads only regular files")

    def warn(self) -> None:
        if self.found:
            warnings.warn(f"{self.root}: {self}", SkippedFilesWarning, stacklevel=3)


def regular_files(paths, root) -> list[Path]:
    """The regular files among `paths` (links followed), in their order; the rest is left out with one warning."""
    skipped, out = SkippedFiles(root), []
    for p in paths:
        kind = special(p)
        if kind:
            skipped.add(str(p), kind)
        else:
            out.append(Path(p))
    skipped.warn()
    return out
