"""Per-episode metrics JSON in the AWS schemas, and racerlab's own per-iteration `metrics.jsonl`.

- `TrainingMetrics`: `{"metrics": [...], "version": 2.0, "best_model_metric": ...}`, one entry per
  episode with the keys of `TRAINING_METRICS_KEYS` (facts §7, `TrainingMetrics` in simapp `s3_metrics.py`).
- `EvalMetrics`: `{"metrics": [...]}` with the keys of `EVAL_METRICS_KEYS` (facts §7, `EvalMetrics`).
- `MetricsLog`: one JSON object per line, appended and flushed; a torn last line (a crash mid-write) is
  ignored when reading.

The JSON documents are rewritten atomically by `save()`; an existing file is loaded on construction so
a resumed training continues the same document. A `TrainingMetrics` given `keep=n` stays small (it is
rewritten every iteration): past 2n entries the oldest all but n move to `TrainingMetrics.archive.jsonl.gz`
beside it (gzip members appended, one JSON entry per line; about a fifteenth of the size), which
`read_training_archive` and `racerlab.analysis.load_metrics` read back in front of the file's entries.
"""

from __future__ import annotations

import gzip
import json
import math
import os
from pathlib import Path

from racerlab.logs.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text
from racerlab.logs.files import MAX_LOG_BYTES, LogFileError, gunzip, open_regular, read_bytes

TRAINING_METRICS_KEYS = ("reward_score", "metric_time", "start_time", "elapsed_time_in_milliseconds",
                         "episode", "trial", "phase", "completion_percentage", "episode_status")
EVAL_METRICS_KEYS = ("completion_percentage", "metric_time", "start_time", "elapsed_time_in_milliseconds",
                     "episode_status", "crash_count", "immobilized_count", "off_track_count",
                     "reversed_count", "reset_count", "trial")
BEST_MODEL_METRICS = ("progress", "reward", "laptime")
# what "best lap" means on every surface of a training (progress lines, metrics.jsonl, report, console, quickstart):
BEST_LAP_NAME = "best eval lap"
BEST_LAP_MEANING = ("the fastest lap completed in the in-training evaluation episodes (greedy actions, as a race "
                    "drives them), over the whole training")
# what picks the best checkpoint, per `[evaluation] best_model_metric`, in the words the surfaces print
BEST_CHECKPOINT_RULES = {
    "progress": "the highest mean evaluation progress, the newest checkpoint on ties (AWS's rule)",
    "reward": "the highest mean evaluation reward, the newest checkpoint on ties",
    "laptime": ("the fastest mean evaluation lap (an unfinished lap counts as 999.999 s), the newest checkpoint within "
                "one step (1/15 s) in one of its laps of the fastest so far"),
}


def best_eval_lap(entries: list[dict]) -> tuple[float, int | None] | None:
    """(seconds, iteration) of the best eval lap (`BEST_LAP_MEANING`) in metrics.jsonl `entries`, the earliest
    iteration on ties; None before the first completed evaluation lap. A training's running record (`best/lap_time`
    and `best/lap_iteration`, in every entry) is read from the newest entry, so the tail of the file is enough; a
    record without its iteration (a training resumed from an older racerlab's checkpoint) gets the earliest entry
    whose own `eval/best_lap` equals it, or None; entries without a record are searched."""
    last = entries[-1] if entries else {}
    record = last.get("best/lap_time")
    if _finite(record):
        it = last.get("best/lap_iteration")
        if not _finite(it):
            it = next((e.get("iteration") for e in entries if e.get("eval/best_lap") == record), None)
        return float(record), (int(it) if _finite(it) else None)
    best = None
    for e in entries:
        lap = e.get("eval/best_lap")
        if _finite(lap) and (best is None or lap < best[0]):
            best = (float(lap), e.get("iteration"))
    return best


def _finite(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def read_metrics_document(path: str | os.PathLike) -> dict:
    """An AWS metrics JSON file (`{"metrics": [...], ...}`); anything else is a one-line `LogFileError`."""
    path = Path(path)
    try:
        doc = json.loads(read_bytes(path).decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise LogFileError(f"{path}: not valid JSON ({e}); delete or repair it to continue") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("metrics"), list):
        raise LogFileError(f"{path}: expected an object with a 'metrics' list")
    return doc


def _check_entry(entry: dict, keys: tuple[str, ...], what: str) -> dict:
    missing = [k for k in keys if k not in entry]
    extra = [k for k in entry if k not in keys]
    if missing or extra:
        raise ValueError(f"{what} entry: missing keys {missing}, unknown keys {extra}")
    return {k: entry[k] for k in keys}


class _MetricsDocument:
    keys: tuple[str, ...] = ()
    what = ""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        doc = read_metrics_document(self.path) if self.path.is_file() else None
        self.metrics: list[dict] = list(doc["metrics"]) if doc else []
        self._doc_extra = {k: v for k, v in (doc or {}).items() if k != "metrics"}

    def add(self, entries: list[dict]) -> None:
        """Append entries (each must have exactly the schema's keys; order is normalised)."""
        self.metrics.extend(_check_entry(e, self.keys, self.what) for e in entries)

    def document(self) -> dict:
        return {"metrics": self.metrics}

    def save(self) -> Path:
        """Write the whole document atomically."""
        return atomic_write_json(self.path, self.document())

    def __len__(self) -> int:
        return len(self.metrics)


class TrainingMetrics(_MetricsDocument):
    """`TrainingMetrics.json`: `add(entries)` per finished episode (training and in-training evaluation
    phases), `save()` atomically. An existing file is loaded so that a resumed training appends to it.

    Entry keys (AWS): reward_score (int, rounded sum of rewards), metric_time and start_time (ms of sim
    time), elapsed_time_in_milliseconds, episode (1-based count of training episodes), trial (1-based index
    in the iteration), phase ("training" | "evaluation"), completion_percentage (int), episode_status (a
    label of `racerlab.spec.STATUS_LABELS`, e.g. "Lap complete").
    """

    keys = TRAINING_METRICS_KEYS
    what = "TrainingMetrics"

    def __init__(self, path: str | os.PathLike, best_model_metric: str = "progress", keep: int = 0):
        if best_model_metric not in BEST_MODEL_METRICS:
            raise ValueError(f"best_model_metric must be one of {BEST_MODEL_METRICS}, got {best_model_metric!r}")
        super().__init__(path)
        self.best_model_metric = best_model_metric
        self.keep = int(keep)
        self.archive = training_archive_path(self.path)

    def document(self) -> dict:
        return {"metrics": self.metrics, "version": 2.0, "best_model_metric": self.best_model_metric}

    def save(self) -> Path:
        """Write the document atomically, first moving the oldest entries to the archive when over 2 * keep."""
        if self.keep and len(self.metrics) > 2 * self.keep:
            old, self.metrics = self.metrics[:-self.keep], self.metrics[-self.keep:]
            data = "".join(json.dumps(e) + "\n" for e in old).encode("utf-8")
            with open(self.archive, "ab") as f:  # a crash before the save below leaves duplicates, read once
                f.write(gzip.compress(data, 6, mtime=0))
                f.flush()
                os.fsync(f.fileno())
        return super().save()

    def truncate(self, last_episode: int) -> None:
        """Drop entries of episodes after `last_episode` (resuming from an older checkpoint)."""
        self.metrics = [m for m in self.metrics if m["episode"] <= last_episode]
        archived = read_training_archive(self.path, [])
        if any(m["episode"] > last_episode for m in archived):
            kept = [m for m in archived if m["episode"] <= last_episode]
            atomic_write_bytes(self.archive, gzip.compress("".join(json.dumps(e) + "\n" for e in kept).encode(),
                                                           6, mtime=0))


def training_archive_path(path: str | os.PathLike) -> Path:
    """`TrainingMetrics.archive.jsonl.gz` beside `TrainingMetrics.json` (no DeepRacer tool's glob matches it)."""
    path = Path(path)
    return path.with_name(path.stem + ".archive.jsonl.gz")


def read_training_archive(path: str | os.PathLike, current: list[dict]) -> list[dict]:
    """The archived entries of the TrainingMetrics file `path`, oldest first, without those also in `current`
    (a crash between archiving and saving); a member torn by a crash ends the read."""
    archive = training_archive_path(path)
    if not archive.is_file():
        return []
    text = gunzip(read_bytes(archive), str(archive), torn_ends=True)
    seen = {(m["episode"], m["trial"], m["phase"]) for m in current}
    entries = (json.loads(line) for line in text.decode("utf-8").splitlines() if line)
    return [e for e in entries if (e["episode"], e["trial"], e["phase"]) not in seen]


class EvalMetrics(_MetricsDocument):
    """`EvalMetrics.json` of one evaluation run: `{"metrics": [...]}`, one entry per trial (lap).

    Entry keys (AWS): completion_percentage, metric_time, start_time, elapsed_time_in_milliseconds,
    episode_status, crash_count, immobilized_count, off_track_count, reversed_count, reset_count (their
    sum) and trial (1-based).
    """

    keys = EVAL_METRICS_KEYS
    what = "EvalMetrics"


class MetricsLog:
    """racerlab's `metrics.jsonl`: `append(entry)` writes one JSON line and flushes it (and fsyncs when
    `fsync`). Non-finite floats are written as null so every line stays valid JSON."""

    def __init__(self, path: str | os.PathLike, fsync: bool = False):
        self.path = Path(path)
        self.fsync = fsync
        self._file = None

    def append(self, entry: dict) -> None:
        line = json.dumps(finite_json(entry), allow_nan=False) + "\n"
        if self._file is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._repair_torn_tail()
            self._file = open(self.path, "a", encoding="utf-8")
        self._file.write(line)
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())

    def read(self) -> list[dict]:
        """All complete entries (a torn last line is skipped; a bad line elsewhere is an error)."""
        return read_metrics_jsonl(self.path)

    def truncate(self, last_iteration: int, key: str = "iteration") -> None:
        """Keep only entries with `entry[key] <= last_iteration` (atomic rewrite)."""
        self.close()
        kept = [e for e in self.read() if e.get(key, -math.inf) <= last_iteration]
        atomic_write_text(self.path, "".join(json.dumps(e, allow_nan=False) + "\n" for e in kept))

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def _repair_torn_tail(self) -> None:
        if self.path.is_file() and self.path.stat().st_size:
            with open(self.path, "rb") as f:
                f.seek(-1, os.SEEK_END)
                ends_clean = f.read(1) == b"\n"
            if not ends_clean:
                self.truncate(math.inf)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_metrics_jsonl(path: str | os.PathLike) -> list[dict]:
    """Entries of a `metrics.jsonl` ([] when missing); a torn final line is ignored, a bad line elsewhere is an
    error naming the file and line."""
    path = Path(path)
    if not path.is_file():
        return []
    *whole, last = read_bytes(path).split(b"\n")
    out = _parse_lines(whole, path, strict=True)
    return out + _parse_lines([last], path, strict=False)  # without its newline: complete, or a write cut off


def follow_metrics_jsonl(path: str | os.PathLike, offset: int = 0) -> tuple[list[dict], int]:
    """For a reader following a training as it writes: the entries of the complete lines after byte `offset`, and
    the offset after the last complete line (a line still being written is read next time; a line that does not
    parse is skipped). A missing file gives ([], offset)."""
    try:
        with open_regular(path) as f:
            f.seek(offset)
            data = f.read(MAX_LOG_BYTES)
    except (OSError, LogFileError):
        return [], offset
    end = data.rfind(b"\n") + 1
    return _parse_lines(data[:end].split(b"\n"), Path(path), strict=False), offset + end


def last_metrics_entry(path: str | os.PathLike, tail_bytes: int = 64 * 1024) -> dict | None:
    """The last complete entry of a `metrics.jsonl`, reading only its last `tail_bytes` (None when there is none)."""
    try:
        with open_regular(path) as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(f.tell() - tail_bytes, 0))
            lines = f.read().split(b"\n")
    except (OSError, LogFileError):
        return None
    for line in reversed(lines):
        found = _parse_lines([line], Path(path), strict=False)
        if found:
            return found[0]
    return None


def _parse_lines(lines: list[bytes], path: Path, strict: bool) -> list[dict]:
    """The JSON entries of `lines` (blank ones skipped); a line that does not parse is a `LogFileError` naming the
    file and line with `strict`, and skipped without."""
    out = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            out.append(json.loads(line))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            if strict:
                raise LogFileError(f"{path}:{i}: not valid JSON ({getattr(e, 'msg', e)})") from None
    return out


def finite_json(obj):
    """NaN and inf become null (and numpy scalars Python numbers), so the JSON stays strict."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite_json(v) for v in obj]
    if hasattr(obj, "item") and hasattr(obj, "dtype"):  # numpy scalar
        return finite_json(obj.item())
    return obj
