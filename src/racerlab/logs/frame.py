"""`load(path)`: one pandas DataFrame of steps from any DeepRacer log source, cached for fast reloads; the one
reader of logs end to end (finding the sources, the cache, parsing, the frame). `racerlab.analysis.load` is this
function: analysis works on the frames it returns.

Sources (see `racerlab.logs.sources`): a racerlab model folder, an AWS/DRfC model folder (single- or
multi-worker, uploads, evaluation-only), a folder of `<n>-iteration.csv` files, robomaker / DROA
simulation logs with `SIM_TRACE_LOG:` lines (rolled `.1`, `.2` parts included), one CSV or log file, or
a console `.tar.gz` export read in place.

Columns, named as deepracer-utils 1.5.6 names them (`DeepRacerLog.dataframe()`): episode, steps, x, y,
yaw (heading, degrees), steering_angle (degrees), speed (commanded m/s), action (-1 for continuous),
reward, done, on_track (all_wheels_on_track), progress, closest_waypoint, track_len, tstamp,
episode_status, pause_duration, obstacle_crash_counter, wall_clock, then iteration, worker and
unique_episode, and stream for evaluations and leaderboard runs. Rows are sorted by unique_episode and
steps. `unique_episode` numbers the episodes 0, 1, ... in (iteration, worker, episode) order (evaluations:
(stream, iteration, episode)); with no episode missing it equals deepracer-utils' number, and it stays
unique when logs were sampled.

Logs from 2019 that carried radians are detected (per file) and converted to degrees; the files
converted are listed in `df.attrs["converted_to_degrees"]`. Their 15-field lines have no episode_status;
it is filled in the way the 2019 environment ended episodes (`derive_status`), and
`df.attrs["derived_status_rows"]` counts the rows filled.
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa

from racerlab.errors import RacerlabWarning
from racerlab.logs.cache import SegmentCache, cache_folder, source_key
from racerlab.logs.files import regular_files
from racerlab.logs.metrics import LogFileError, read_metrics_document, read_training_archive
from racerlab.logs.read import (
    MEMORY,
    RAW_COLUMNS,
    decompress,
    looks_like_radians,
    read_sim_trace_log,
    read_simtrace_csvs,
    read_simtrace_files,
    to_degrees,
)
from racerlab.logs.sources import (
    CSV,
    EVALUATION,
    LEADERBOARD,
    LOG,
    TRAINING,
    DirStore,
    Source,
    Store,
    classify,
    open_store,
)

KINDS = (TRAINING, EVALUATION, LEADERBOARD)
FRAME_COLUMNS = (*RAW_COLUMNS, "iteration", "worker", "unique_episode")
DEFAULT_EPISODES_PER_ITERATION = 20  # deepracer-utils' default when a log has no hyperparameters


def load(path: str | os.PathLike, kind: str = "auto", *, cache: bool = True,
         cache_dir: str | os.PathLike | None = None, threads: bool = True) -> pd.DataFrame:
    """Steps of the training (or evaluation / leaderboard) runs found at `path`, one row per step.

    kind: "training", "evaluation", "leaderboard" or "auto" (training when there is any, else
    evaluation, else leaderboard). cache: keep a Parquet copy of the parsed files under `cache_dir`
    (see `racerlab.logs.cache`) so that a reload reads only new or changed files. threads: read and
    parse the CSV files on a pool of threads (False: one file after another in this thread).
    """
    if kind != "auto" and kind not in KINDS:
        raise ValueError(f"kind must be 'auto' or one of {KINDS}, got {kind!r}")
    store = open_store(path)
    try:
        sources = classify(store.files(), single=getattr(store, "single", None) is not None)
        kind, chosen = _choose(sources, kind, path, getattr(store, "skipped", None))
        tables, info = _tables(store, chosen, kind, path, cache, cache_dir, threads)
    finally:
        if hasattr(store, "close"):
            store.close()
    return drop_absurd_rows(_frame(tables, kind, info), path)


MAX_COORDINATE_M = 1e4  # the largest AWS track spans about 60 m; a position past 10 km is a corrupt row


def drop_absurd_rows(df: pd.DataFrame, path) -> pd.DataFrame:
    """Drop rows whose x or y is not finite or lies past MAX_COORDINATE_M (a damaged or forged simtrace): they
    would stretch every plot. One warning says how many and where; `df.attrs["dropped_rows"]` counts them."""
    if df.empty or "x" not in df.columns or "y" not in df.columns:
        return df
    xy = df[["x", "y"]].to_numpy(dtype=np.float64)
    bad = ~(np.abs(xy) <= MAX_COORDINATE_M).all(axis=1)
    n = int(bad.sum())
    df.attrs["dropped_rows"] = n
    if not n:
        return df
    first = df.loc[bad].iloc[0]
    warnings.warn(f"{path}: dropped {n} simtrace row(s) with x or y not finite or beyond {MAX_COORDINATE_M:g} m "
                  f"(first: episode {first.get('episode')}, step {first.get('steps')}, x={first['x']:g}, "
                  f"y={first['y']:g}); the file is damaged there", RacerlabWarning, stacklevel=3)
    attrs = dict(df.attrs)
    out = df.loc[~bad].reset_index(drop=True)
    out.attrs.update(attrs)
    return out


def _choose(sources: list[Source], kind: str, path, skipped=None) -> tuple[str, list[Source]]:
    """(kind, its sources); the entries of a folder that were no regular files (`skipped`) are named once, in the
    warning beside what was found or in the one line saying nothing was."""
    kinds = [kind] if kind != "auto" else list(KINDS)
    for k in kinds:
        of_kind = [s for s in sources if s.kind == k]
        csvs = [s for s in of_kind if s.fmt == CSV]
        if csvs or of_kind:
            if skipped is not None:
                skipped.warn()
            return k, csvs or of_kind  # a CSV and a robomaker log hold the same steps: prefer the CSV
    what = "step logs" if kind == "auto" else f"{kind} step logs"
    left = f"; {skipped}" if skipped is not None and skipped.found else ""
    raise LogFileError(f"{path}: found no {what} (looked for training-simtrace/<n>-iteration.csv, "
                       f"evaluation-*/evaluation-simtrace/<n>-iteration.csv and *.log files with SIM_TRACE_LOG lines)"
                       f"{left}")


def _tables(store: Store, sources: list[Source], kind: str, path, cache: bool, cache_dir, threads: bool):
    keys = [source_key(s.parts, s.stats) for s in sources]
    seg = SegmentCache(cache_folder(cache_dir, path, kind)) if cache else None
    tables, entries, covered = seg.lookup(keys) if seg else ([], [], set())
    todo = [(s, k) for s, k in zip(sources, keys, strict=True) if k not in covered]
    info = {"converted_to_degrees": [f for e in entries for f in e.get("info", {}).get("converted_to_degrees", [])]}
    if todo:
        fresh, fresh_info = _parse_sources(store, [s for s, _ in todo], threads)
        tables.append(fresh)
        info["converted_to_degrees"] += fresh_info["converted_to_degrees"]
        if seg is not None:
            try:
                seg.add([k for _, k in todo], fresh, fresh_info)
            except OSError:
                pass  # a cache that cannot be written only costs speed
    return tables, info


def _parse_sources(store: Store, sources: list[Source], threads: bool) -> tuple[pa.Table, dict]:
    # files in frame order (iteration, then worker) make the final sort a no-op
    csvs = sorted((s for s in sources if s.fmt == CSV), key=lambda s: (s.stream, s.iteration, s.worker))
    logs = [s for s in sources if s.fmt == LOG]
    parts = []
    if csvs:
        table, counts = _read_csvs(store, csvs, threads)
        parts.append(_with_meta(table, csvs, counts))
    converted = []
    for s in logs:
        table, radians = _parse_log(store, s)
        parts.append(table)
        if radians:
            converted.append(store.describe(s.name))
    return pa.concat_tables(parts), {"converted_to_degrees": converted}


def _read_csvs(store: Store, csvs: list[Source], threads: bool) -> tuple[pa.Table, np.ndarray]:
    rels = [s.parts[0] for s in csvs]
    described = [store.describe(r) for r in rels]
    if isinstance(store, DirStore):
        return read_simtrace_files([str(store.root / r) for r in rels], described, threads)
    blobs = _read_many(store, rels)
    return read_simtrace_csvs([(d, blobs[r]) for d, r in zip(described, rels, strict=True)], threads)


def _read_many(store: Store, rels: list[str]) -> dict[str, bytes]:
    if hasattr(store, "read_many"):
        return store.read_many(rels)
    return {r: store.read(r) for r in rels}


def _parse_log(store: Store, s: Source) -> tuple[pa.Table, bool]:
    data = b"".join(_ensure_newline(decompress(store.read(p), p)) for p in s.parts)
    table, info = read_sim_trace_log(data, store.describe(s.name))
    radians = looks_like_radians(table.column("yaw").to_numpy(), table.column("steering_angle").to_numpy())
    if radians:
        table = to_degrees(table)
    if s.kind == TRAINING:
        hp = info.get("hyperparameters") or {}
        episodes = int(hp.get("num_episodes_between_training") or DEFAULT_EPISODES_PER_ITERATION)
        per_worker = max(1, round(episodes / s.workers))  # DRfC divides an iteration's episodes among workers
        iterations = table.column("episode").to_numpy() // per_worker
    else:
        iterations = np.zeros(table.num_rows, np.int64)
    n = table.num_rows
    return _append(table, iterations, np.full(n, s.worker), [s.stream], np.zeros(n, np.int32)), radians


def _ensure_newline(data: bytes) -> bytes:
    return data if data.endswith(b"\n") or not data else data + b"\n"


def _with_meta(table: pa.Table, sources: list[Source], counts: np.ndarray) -> pa.Table:
    iteration = np.repeat([s.iteration for s in sources], counts)
    worker = np.repeat([s.worker for s in sources], counts)
    names, codes = np.unique([s.stream for s in sources], return_inverse=True)
    return _append(table, iteration, worker, list(names), np.repeat(codes.astype(np.int32), counts))


def _append(table: pa.Table, iteration, worker, streams: list[str], stream_codes: np.ndarray) -> pa.Table:
    table = table.append_column("iteration", pa.array(np.asarray(iteration, np.int64)))
    table = table.append_column("worker", pa.array(np.asarray(worker, np.int64)))
    stream = pa.DictionaryArray.from_arrays(pa.array(stream_codes, pa.int32()), pa.array(streams, pa.string()))
    return table.append_column("stream", stream)


# ---------------------------------------------------------------------------------------------------------
# metrics JSON


def load_metrics(path: str | os.PathLike, kind: str = "training") -> pd.DataFrame:
    """Per-episode metrics as a DataFrame: `TrainingMetrics*.json` (kind "training": a file, or a model
    folder's `metrics/`, one worker per `_k` suffix) or `EvalMetrics.json` (kind "evaluation": a file, or
    every `evaluation-<stamp>/` of a model folder, with `stream`).

    Training rows get `worker` and `iteration` = (episode - 1) // episodes per iteration, where the latter is
    the largest `trial` (deepracer-utils' rule); missing files are a `LogFileError`.
    """
    path = Path(path)
    if kind not in (TRAINING, EVALUATION):
        raise ValueError(f"kind must be 'training' or 'evaluation', got {kind!r}")
    files = _metrics_files(path, kind)
    if not files:
        raise LogFileError(f"{path}: no {'TrainingMetrics*.json' if kind == TRAINING else 'EvalMetrics.json'} found")
    frames = []
    for f, label in files:
        entries = read_metrics_document(f)["metrics"]
        if kind == TRAINING:
            entries = read_training_archive(f, entries) + entries  # the oldest entries of a long training
        df = pd.DataFrame(entries)
        if kind == TRAINING:
            df["worker"] = int(label)
        else:
            df["stream"] = label
        frames.append(df)
    df = pd.concat(frames, ignore_index=True)
    if kind == TRAINING and len(df):
        per_iteration = max(int(df.loc[df["worker"] == df["worker"].min(), "trial"].max()), 1)
        df["iteration"] = (df["episode"] - 1) // per_iteration
    return df


def _metrics_files(path: Path, kind: str) -> list[tuple[Path, str]]:
    if path.is_file():
        return [(path, _metrics_label(path, kind))]
    if kind == TRAINING:
        found = sorted(path.glob("metrics/TrainingMetrics*.json")) or sorted(path.glob("TrainingMetrics*.json"))
    else:
        found = sorted(path.glob("evaluation-*/EvalMetrics.json")) or sorted(path.glob("EvalMetrics.json"))
    return [(f, _metrics_label(f, kind)) for f in regular_files(found, path)]


def _metrics_label(f: Path, kind: str) -> str:
    if kind == TRAINING:
        m = re.search(r"_(\d+)\.json$", f.name)
        return m.group(1) if m else "0"
    m = re.match(r"evaluation-(\d{14})$", f.parent.name)
    return m.group(1) if m else f.parent.name


# ---------------------------------------------------------------------------------------------------------
# the frame


def _frame(tables: list[pa.Table], kind: str, info: dict) -> pd.DataFrame:
    tables = [_unify(t) for t in tables if t.num_rows]
    if not tables:
        df = pd.DataFrame({c: pd.Series(dtype="float64") for c in FRAME_COLUMNS})
        df.attrs.update(kind=kind, **info)
        return df
    table = pa.concat_tables(tables, promote_options="permissive") if len(tables) > 1 else tables[0]
    df = table.to_pandas(split_blocks=True, self_destruct=True, memory_pool=MEMORY)
    keys = _sort_keys(df, kind)
    if not _is_sorted(keys):
        order = np.lexsort(keys[::-1])
        df = df.take(order).reset_index(drop=True)
        keys = [k[order] for k in keys]
    df["unique_episode"] = _dense_rank(keys[:-1])
    info["derived_status_rows"] = _fill_status(df)
    if kind == TRAINING:
        df = df.drop(columns=["stream"])
    for col in ("episode_status", "stream"):
        if col in df.columns:
            df[col] = df[col].astype("category")
    df = _columns_in_order(df)
    df.attrs.update(kind=kind, **info)
    return df


def _unify(table: pa.Table) -> pa.Table:
    """Dictionary columns from different segments may differ in index type; make them all the same."""
    cols = []
    for name in table.column_names:
        col = table.column(name)
        if pa.types.is_dictionary(col.type):
            col = col.cast(pa.dictionary(pa.int32(), pa.string()))
        cols.append(col)
    return pa.table(cols, names=table.column_names)


def _sort_keys(df: pd.DataFrame, kind: str) -> list[np.ndarray]:
    """Episode identity keys (most significant first), then steps."""
    it = df["iteration"].to_numpy()
    ep = df["episode"].to_numpy()
    steps = df["steps"].to_numpy()
    if kind == TRAINING:
        return [it, df["worker"].to_numpy(), ep, steps]
    stream = pd.Categorical(df["stream"].astype(str)).codes.astype(np.int64)
    return [stream, it, ep, steps]


def _is_sorted(keys: list[np.ndarray]) -> bool:
    """Whether rows are already in lexicographic order of `keys` (files are usually written in order)."""
    before = np.zeros(keys[0].size - 1 if keys[0].size else 0, bool)
    equal = ~before
    for k in keys:
        before |= equal & (k[:-1] < k[1:])
        equal &= k[:-1] == k[1:]
    return bool((before | equal).all())


def _dense_rank(sorted_keys: list[np.ndarray]) -> np.ndarray:
    n = sorted_keys[0].size
    change = np.zeros(n, bool)
    if n:
        change[0] = False
        for k in sorted_keys:
            change[1:] |= k[1:] != k[:-1]
    return np.cumsum(change).astype(np.int64)


def derive_status(steps, done, on_track, progress) -> np.ndarray:
    """Episode status of rows logged without one (2019 robomaker logs), as the 2019 environment behaved:
    its reset row (steps 0: car held at the start, action 0, a reward no agent received) is `prepare`; a
    done row at progress 100 is `lap_complete`; done with wheels off the road `off_track`; done on the
    road `immobilized` (its stuck rule); anything else `in_progress`."""
    done = np.asarray(done, bool)
    status = np.where(done & ~np.asarray(on_track, bool), "off_track", np.where(done, "immobilized", "in_progress"))
    status = np.where(done & (np.asarray(progress) >= 100.0), "lap_complete", status)
    return np.where(np.asarray(steps) == 0, "prepare", status)


def _fill_status(df: pd.DataFrame) -> int:
    missing = df["episode_status"].isna().to_numpy()
    if not missing.any():
        return 0
    rows = np.flatnonzero(missing)
    derived = derive_status(*(df[c].to_numpy()[rows] for c in ("steps", "done", "on_track", "progress")))
    status = np.array(df["episode_status"].astype(object), dtype=object)
    status[rows] = derived
    df["episode_status"] = status
    return int(rows.size)


def _columns_in_order(df: pd.DataFrame) -> pd.DataFrame:
    cols = [c for c in FRAME_COLUMNS if c in df.columns] + [c for c in df.columns if c not in FRAME_COLUMNS]
    return df[cols]


__all__ = ["FRAME_COLUMNS", "derive_status", "load", "load_metrics"]
