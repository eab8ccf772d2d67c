"""A columnar cache of parsed logs: Parquet segments plus a manifest of which source files they hold.

A source file is identified by its path, size and modification time. On a reload the segments whose
files are all unchanged are read back (fast: Parquet, no text parsing); files that are new or changed
are parsed and stored as a new segment, so a training that adds iterations costs only the new ones.
A segment that holds a changed or deleted file is dropped (its other files are parsed again). Many
small segments are merged into one now and then.

The cache lives in the user's cache folder (`$RACERLAB_CACHE_DIR`, else `$XDG_CACHE_HOME/racerlab/logs`,
else `~/.cache/racerlab/logs`), one subfolder per loaded path and kind, never inside the log folder
(which may be a read-only mount or a MinIO bucket).
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from racerlab.logs.atomic import atomic_write_json, temp_path_for

CACHE_VERSION = 1
MAX_SEGMENTS = 12


def default_cache_root() -> Path:
    if os.environ.get("RACERLAB_CACHE_DIR"):
        return Path(os.environ["RACERLAB_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "racerlab" / "logs"


def cache_folder(root: str | os.PathLike | None, source_path: str | os.PathLike, kind: str) -> Path:
    """The cache subfolder for one loaded path and kind."""
    key = f"{Path(source_path).resolve()}|{kind}|v{CACHE_VERSION}"
    digest = hashlib.sha1(key.encode("utf-8")).hexdigest()[:16]
    return Path(root or default_cache_root()) / f"{Path(source_path).name[:40]}-{digest}"


def source_key(parts: list[str], stats: list[tuple[int, int]]) -> str:
    return "|".join(f"{p}:{size}:{mtime}" for p, (size, mtime) in zip(parts, stats, strict=True))


class SegmentCache:
    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        self.manifest_path = self.folder / "manifest.json"
        self.segments: list[dict] = self._read_manifest()

    def _read_manifest(self) -> list[dict]:
        try:
            doc = json.loads(self.manifest_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return []
        if not isinstance(doc, dict) or doc.get("version") != CACHE_VERSION:
            return []
        return [s for s in doc.get("segments", []) if (self.folder / s.get("file", "")).is_file()]

    def lookup(self, keys: list[str]) -> tuple[list[pa.Table], list[dict], set[str]]:
        """(tables of valid segments, their manifest entries, the keys they cover); invalid ones are removed."""
        wanted = set(keys)
        tables, entries, covered = [], [], set()
        for seg in list(self.segments):
            if not set(seg["keys"]) <= wanted:
                self._drop(seg)
                continue
            try:
                tables.append(pq.read_table(self.folder / seg["file"]))
            except (OSError, pa.ArrowException):
                self._drop(seg)
                continue
            entries.append(seg)
            covered.update(seg["keys"])
        self._remove_orphans()
        return tables, entries, covered

    def _remove_orphans(self, min_age_s: float = 3600.0) -> None:
        """Segments no manifest names (a concurrent load won the manifest race) once they are old."""
        if not self.folder.is_dir():
            return
        named = {s["file"] for s in self.segments}
        now = time.time()
        for p in self.folder.glob("segment-*.parquet"):
            try:
                if p.name not in named and now - p.stat().st_mtime > min_age_s:
                    p.unlink()
            except OSError:
                pass

    def add(self, keys: list[str], table: pa.Table, info: dict | None = None) -> None:
        """Store `table` (the rows of the sources `keys`) as a new segment; merge when there are many."""
        if not keys:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        name = f"segment-{secrets.token_hex(6)}.parquet"
        _write_parquet(table, self.folder / name)
        self.segments.append({"file": name, "keys": keys, "rows": table.num_rows, "info": info or {}})
        if len(self.segments) > MAX_SEGMENTS:
            self._compact()
        self._save()

    def _compact(self) -> None:
        tables = [pq.read_table(self.folder / s["file"]) for s in self.segments]
        merged = {"file": f"segment-{secrets.token_hex(6)}.parquet",
                  "keys": [k for s in self.segments for k in s["keys"]],
                  "rows": sum(t.num_rows for t in tables),
                  "info": _merge_info([s.get("info", {}) for s in self.segments])}
        _write_parquet(pa.concat_tables(tables), self.folder / merged["file"])
        old = self.segments
        self.segments = [merged]
        self._save()
        for s in old:
            (self.folder / s["file"]).unlink(missing_ok=True)

    def _drop(self, seg: dict) -> None:
        self.segments.remove(seg)
        (self.folder / seg["file"]).unlink(missing_ok=True)
        self._save()

    def _save(self) -> None:
        if self.folder.is_dir():
            atomic_write_json(self.manifest_path, {"version": CACHE_VERSION, "segments": self.segments},
                              fsync=False)


def _merge_info(infos: list[dict]) -> dict:
    out: dict = {}
    for info in infos:
        for k, v in info.items():
            out.setdefault(k, []).extend(v)
    return out


def _write_parquet(table: pa.Table, path: Path) -> None:
    tmp = temp_path_for(path)
    try:
        pq.write_table(table, tmp, compression="zstd", compression_level=1)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
