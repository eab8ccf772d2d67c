"""Keeping a model's training simtrace within a disk budget while its readers still read it.

deepracer-utils 1.5.6 globs `training-simtrace/*-iteration.csv` and hands the bytes to `pandas.read_csv`
undecompressed, so it reads plain CSV only; it also counts episodes per iteration from iteration 0.
So the files are kept in three tiers:

- iteration 0 and the newest `plain` iterations stay plain `<n>-iteration.csv` (deepracer-utils reads them);
- older iterations are gzipped in place to `<n>-iteration.csv.gz` (about 4x smaller; `racerlab.analysis.load`
  reads them with the plain ones);
- while the folder is over `max_bytes`, the gzipped iterations are thinned, the least thinned and oldest
  first: a thinning keeps the rows of episodes whose number is a multiple of 2**(k+1) where 2**k divided
  them all, which halves the episodes of a file that held consecutive ones. Episode numbers count across
  iterations, so a file thinned past its last episode is removed (episode 0 is never dropped): the
  history keeps evenly spaced whole episodes, densest in the newest iterations.

When the gzipped files are all gone and the folder is still over budget, the oldest plain iterations are
gzipped (and then thinned) too; only iteration 0 and the newest iteration are never touched.
"""

from __future__ import annotations

import gzip
import os
import re
from pathlib import Path

import numpy as np

from racerlab.logs.atomic import atomic_write_bytes

_FILE = re.compile(r"^(\d+)-iteration\.csv(\.gz)?$")
COMPRESS_LEVEL = 6
_ONLY_ZERO = 1 << 30  # the level of a file holding only episode 0: it cannot be thinned


def _episodes(body: bytes) -> tuple[list[bytes], np.ndarray]:
    """The row lines of a simtrace body (no header) and each row's episode number (the first column)."""
    lines = [line for line in body.split(b"\n") if line]
    return lines, np.array([int(line[:line.index(b",")]) for line in lines], dtype=np.int64)


def _lowest_power(episodes: np.ndarray) -> int | None:
    """k such that 2**k divides every non-zero episode number and 2**(k+1) does not; None when only 0s."""
    nonzero = episodes[episodes > 0]
    if not nonzero.size:
        return None
    return int(np.min(nonzero & -nonzero)).bit_length() - 1


def thin_simtrace(data: bytes) -> bytes | None:
    """One thinning step of a simtrace CSV text (header first): the rows of the episodes whose number is a
    multiple of 2**(k+1), where 2**k is the largest power of two dividing all of them (episode 0 stays).
    None when no row is left; the same text when it cannot be thinned (only episode 0)."""
    header, _, body = data.partition(b"\n")
    lines, episodes = _episodes(body)
    k = _lowest_power(episodes)
    if k is None:
        return data
    keep = episodes % (2 ** (k + 1)) == 0
    if not keep.any():
        return None
    return header + b"\n" + b"".join(line + b"\n" for line, kept in zip(lines, keep, strict=True) if kept)


class SimtraceRetention:
    """The disk budget of one `training-simtrace/` folder. `enforce()` after each new iteration's file.

    plain: how many of the newest iterations stay plain CSV (besides iteration 0); max_bytes: the budget
    for the folder's simtrace files (0 = none: older iterations are still gzipped, never thinned).
    """

    def __init__(self, folder: str | os.PathLike, plain: int, max_bytes: int):
        if plain < 1 or max_bytes < 0:
            raise ValueError(f"plain must be >= 1 and max_bytes >= 0, got {plain}, {max_bytes}")
        self.folder = Path(folder)
        self.plain = int(plain)
        self.max_bytes = int(max_bytes)
        self.thinned: list[str] = []  # what the last enforce() did, for a note
        self.rescan()

    def rescan(self) -> None:
        """Read the folder again (after files were removed or written by someone else)."""
        self.files: dict[int, Path] = {}
        self.sizes: dict[int, int] = {}
        self.level: dict[int, int] = {}  # lower bound of k (see thin_simtrace) per gzipped iteration
        if not self.folder.is_dir():
            return
        for p in sorted(self.folder.iterdir()):
            m = _FILE.match(p.name)
            if not m:
                continue
            n = int(m.group(1))
            if n in self.files:  # both plain and .gz: a compaction was stopped between the two steps
                plain, packed = (p, self.files[n]) if p.suffix == ".csv" else (self.files[n], p)
                plain.unlink(missing_ok=True)
                p = packed
            self.files[n], self.sizes[n] = p, p.stat().st_size

    def total(self) -> int:
        return sum(self.sizes.values())

    def added(self, iteration: int, path: str | os.PathLike) -> None:
        """Record a newly written iteration file."""
        path = Path(path)
        self.files[iteration], self.sizes[iteration] = path, path.stat().st_size

    def enforce(self, reserve: int = 0) -> list[str]:
        """Gzip iterations older than the plain window, then thin until the folder fits in max_bytes - reserve
        (the bytes other logs under the same budget take). Returns what it did."""
        done = []
        newest = max(self.files, default=0)
        for n in list(self.files):
            if 0 < n <= newest - self.plain and self.files[n].suffix == ".csv":
                self._pack(n)
        if self.max_bytes:
            done += self._thin_to_budget(newest, self.max_bytes - reserve)
        self.thinned = done
        return done

    def _pack(self, n: int) -> None:
        plain = self.files[n]
        packed = plain.with_name(plain.name + ".gz")
        atomic_write_bytes(packed, gzip.compress(plain.read_bytes(), COMPRESS_LEVEL, mtime=0), fsync=False)
        plain.unlink()
        self.files[n], self.sizes[n] = packed, packed.stat().st_size

    def _thin_to_budget(self, newest: int, budget: int) -> list[str]:
        done = []
        while self.total() > budget:
            packed = [n for n, p in self.files.items()
                      if p.suffix == ".gz" and 0 < n < newest and self.level.get(n, 0) < _ONLY_ZERO]
            if packed:
                n = min(packed, key=lambda i: (self.level.get(i, 0), i))
                done.append(self._thin(n))
                continue
            plain = [n for n, p in self.files.items() if p.suffix == ".csv" and 0 < n < newest]
            if not plain:
                break  # iteration 0 and the newest iteration alone are over budget
            self._pack(min(plain))
        return [d for d in done if d]

    def _thin(self, n: int) -> str:
        path = self.files[n]
        data = gzip.decompress(path.read_bytes())
        thinned = thin_simtrace(data)
        if thinned is None:
            path.unlink()
            del self.files[n], self.sizes[n]
            self.level.pop(n, None)
            return f"{path.name} removed"
        if thinned is data:  # only episode 0 left: nothing to halve, keep it out of the way
            self.level[n] = _ONLY_ZERO
            return ""
        _, episodes = _episodes(thinned.partition(b"\n")[2])
        self.level[n] = _lowest_power(episodes) or 0
        atomic_write_bytes(path, gzip.compress(thinned, COMPRESS_LEVEL, mtime=0), fsync=False)
        self.sizes[n] = path.stat().st_size
        return f"{path.name} thinned"
