"""What a taught run's learner keeps beside its checkpoints (`ModelFolder.dagger_dir`, checkpoints/dagger/): DAgger's
aggregated data set and the fit's optimiser, so that a resumed run goes on with every round's labelled steps (round
0's: the teacher's own driving) and the fit's moments, as the PPO agent goes on with its own optimiser.

One file per committed iteration, `<iteration>.npz`, of numpy arrays only (loading it runs no pickle): the data
set's rows written since the previous file (their slots and columns), or all of its rows (a snapshot: the first
file, and whenever the files after the last snapshot would hold more rows than the set holds), the fit's optimiser
state after that iteration, and a JSON line of counters. A file is written under a temporary name and renamed onto
its own, so the store holds whole files only, and at most about twice the data set. Reading checks every array's
header before the array is read: its rows within the set's capacity, its row shape and type those of the
student's inputs, so a damaged or foreign file costs one line and an empty set, never a huge allocation.
"""

from __future__ import annotations

import json
import math
import os
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from racerlab.logs.atomic import commit_temp, temp_path_for

FORMAT = "racerlab.dagger/1"
FILE_RE = re.compile(r"^(\d+)\.npz$")
META = "meta"  # the JSON counters, a 0-d unicode array
SLOTS = "slots"


class StoreError(Exception):
    """A store file that cannot be read back as this run's data set (damaged, foreign, another student's)."""


@dataclass
class Loaded:
    """What a store gives back for a resume: the rows of the set, by slot, and the fit's state."""

    columns: dict[str, np.ndarray]  # {name: [size, ...]}
    size: int
    seen: int
    rng: dict  # the set's numpy bit-generator state
    capacity: int
    fit: dict[str, np.ndarray]  # the fit's optimiser tensors and generator, by name
    fit_meta: dict  # the optimiser's param_groups and the file's rate


def _header(f) -> tuple[tuple[int, ...], np.dtype]:
    version = np.lib.format.read_magic(f)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read(f)
    return tuple(int(n) for n in shape), np.dtype(dtype)


class DaggerStore:
    """The files of one model's store in `path`; `expected` is {column: (row shape, dtype)} of the student's inputs
    and the teacher's features, `capacity` the set's size (teacher.max_steps)."""

    def __init__(self, path: Path, expected: dict[str, tuple[tuple[int, ...], np.dtype]], capacity: int,
                 fit_bytes: int):
        self.path = Path(path)
        self.expected = {k: (tuple(shape), np.dtype(dtype)) for k, (shape, dtype) in expected.items()}
        self.capacity = int(capacity)
        row = sum(math.prod(shape) * dtype.itemsize for shape, dtype in self.expected.values()) + 8  # and its slot
        # what a file may hold at most: twice the set (a larger teacher.max_steps before) and the fit's state
        self.max_bytes = 2 * self.capacity * row + int(fit_bytes) + (1 << 20)
        self.logged: int | None = None  # rows in the files after the newest snapshot (None: the next is one)

    def files(self) -> list[tuple[int, Path]]:
        if not self.path.is_dir():
            return []
        found = [(int(m.group(1)), p) for p in self.path.iterdir() if (m := FILE_RE.match(p.name)) and p.is_file()]
        return sorted(found)

    # ---- writing -------------------------------------------------------------------------------------------
    def save(self, iteration: int, columns: dict[str, np.ndarray], size: int, slots: np.ndarray, counters: dict,
             fit: dict[str, np.ndarray], fit_meta: dict) -> Path:
        """The file of `iteration`: the rows at `slots` of `columns` (each [capacity, ...], `size` rows filled),
        or a snapshot of all `size` rows when one is due; `counters` (seen, rng) and the fit's state with it."""
        slots = np.unique(np.asarray(slots, dtype=np.int64))
        snapshot = self.logged is None or self.logged + len(slots) > self.capacity
        if snapshot:
            slots = np.arange(size, dtype=np.int64)
        meta = {"format": FORMAT, "iteration": int(iteration), "capacity": self.capacity, "size": int(size),
                "snapshot": snapshot, "columns": sorted(columns), **counters, "fit": fit_meta}
        arrays = {META: np.array(json.dumps(meta)), SLOTS: slots,
                  **{f"col{i}": columns[name][slots] for i, name in enumerate(sorted(columns))},
                  **{f"fit.{k}": v for k, v in fit.items()}}
        target = self.path / f"{int(iteration)}.npz"
        self.path.mkdir(parents=True, exist_ok=True)
        tmp = temp_path_for(target)
        try:
            with open(tmp, "wb") as f:
                np.savez(f, **arrays)
                f.flush()
                os.fsync(f.fileno())
            commit_temp(tmp, target)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        if snapshot:  # the older files are replayed no more
            for it, p in self.files():
                if it < iteration:
                    p.unlink(missing_ok=True)
            self.logged = 0
        else:
            self.logged += len(slots)
        return target

    def drop_after(self, iteration: int) -> None:
        """Forget the files of iterations after a checkpoint a run resumes from."""
        for it, p in self.files():
            if it > iteration:
                p.unlink(missing_ok=True)

    def clear(self) -> None:
        for _, p in self.files():
            p.unlink(missing_ok=True)
        self.logged = None

    # ---- reading -------------------------------------------------------------------------------------------
    def load(self, iteration: int) -> Loaded | None:
        """The set as of checkpoint `iteration`: the newest snapshot at or before it, then the files after that
        snapshot up to it; None when the store has none. Raises StoreError for a file it cannot take."""
        self.drop_after(iteration)
        files = self.files()
        if not files:
            self.logged = None
            return None
        reads = [self._read(p) for _, p in files]
        start = max((i for i, (meta, _) in enumerate(reads) if meta["snapshot"]), default=None)
        if start is None:
            raise StoreError(f"{files[0][1]}: no snapshot of the data set at or before iteration {iteration}")
        loaded = None
        for meta, arrays in reads[start:]:
            loaded = self._apply(loaded, meta, arrays)
        self.logged = sum(len(arrays[SLOTS]) for _, arrays in reads[start + 1:])
        if self.capacity != loaded.capacity:
            self.logged = None  # the slots change with the capacity: the next file is a snapshot
        return loaded

    def _apply(self, loaded: Loaded | None, meta: dict, arrays: dict) -> Loaded:
        if loaded is None:
            cap = meta["capacity"]
            cols = {k: np.empty((cap, *shape), dtype) for k, (shape, dtype) in self.expected.items()}
            loaded = Loaded(cols, 0, 0, {}, cap, {}, {})
        elif meta["capacity"] != loaded.capacity:
            raise StoreError(f"iteration {meta['iteration']}: capacity {meta['capacity']} after {loaded.capacity}")
        slots = arrays[SLOTS]
        for i, name in enumerate(meta["columns"]):
            loaded.columns[name][slots] = arrays[f"col{i}"]
        loaded.size, loaded.seen, loaded.rng = meta["size"], meta["seen"], meta["rng"]
        loaded.fit = {k[4:]: v for k, v in arrays.items() if k.startswith("fit.")}
        loaded.fit_meta = meta["fit"]
        return loaded

    def _read(self, path: Path) -> tuple[dict, dict[str, np.ndarray]]:
        """A file's counters and arrays, every header checked before its array is read."""
        try:
            self._check_headers(path)
            with np.load(path, allow_pickle=False) as z:
                arrays = {name: z[name] for name in z.files}
            meta = json.loads(str(arrays.pop(META)))
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise StoreError(f"{path}: not a readable DAgger data set file ({type(exc).__name__}: {exc})") from None
        self._check(path, meta, arrays)
        return meta, arrays

    def _check_headers(self, path: Path) -> None:
        """Every array's declared shape and type, before any is read: no objects, nothing larger than its own
        member of the file, the columns in the student's row shapes, all of it within `max_bytes`."""
        rows = {shape for shape, _ in self.expected.values()}
        total = 0
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():
                with z.open(info) as f:
                    shape, dtype = _header(f)
                nbytes = math.prod(shape) * dtype.itemsize
                total += nbytes
                if dtype.hasobject or nbytes > info.file_size:
                    raise StoreError(f"{path}: {info.filename} declares {shape} of {dtype}, not what it holds")
                if info.filename.startswith("col") and (not shape or shape[1:] not in rows):
                    raise StoreError(f"{path}: {info.filename} has rows of {shape[1:]}, not the student's inputs")
        if total > self.max_bytes:
            raise StoreError(f"{path}: declares {total} bytes, more than a data set of {self.capacity} steps holds")

    def _check(self, path: Path, meta: dict, arrays: dict) -> None:
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise StoreError(f"{path}: not a racerlab DAgger data set file (format {meta.get('format')!r})")
        cap, size, slots = meta.get("capacity"), meta.get("size"), arrays.get(SLOTS)
        if not (isinstance(cap, int) and isinstance(size, int) and 0 <= size <= cap <= 2 * self.capacity):
            raise StoreError(f"{path}: size {size!r} and capacity {cap!r} do not fit teacher.max_steps "
                             f"{self.capacity}")
        if slots is None or slots.ndim != 1 or slots.dtype.kind != "i" or (
                len(slots) and (slots.min() < 0 or slots.max() >= max(size, 1))):
            raise StoreError(f"{path}: its slots are not rows of a set of {size} steps")
        if sorted(meta.get("columns") or []) != sorted(self.expected):
            raise StoreError(f"{path}: columns {meta.get('columns')} where this student has {sorted(self.expected)}")
        for i, name in enumerate(meta["columns"]):
            col = arrays.get(f"col{i}")
            shape, dtype = self.expected[name]
            if col is None or col.shape != (len(slots), *shape) or col.dtype != dtype:
                raise StoreError(f"{path}: column {name} is {None if col is None else (col.shape, col.dtype)}, "
                                 f"not {len(slots)} rows of {shape} {dtype}")
            if col.dtype.kind == "f" and not np.isfinite(col).all():
                raise StoreError(f"{path}: column {name} holds non-finite values")
