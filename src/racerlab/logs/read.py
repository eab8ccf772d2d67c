"""Parsing simtrace CSVs and `SIM_TRACE_LOG:` lines into Arrow tables with deepracer-utils' column names.

Both carriers end up in the same columns (`RAW_COLUMNS`): the CSV names `X, Y, steer, throttle,
all_wheels_on_track` become `x, y, steering_angle, speed, on_track` as deepracer-utils 1.5.6 names them
(`yaw` keeps its name there too). Missing columns of older formats are filled: `episode_status` with
nulls, `pause_duration`, `obstacle_crash_counter` and `wall_clock` with NaN. A continuous action
(`[steer speed]`, or the older `[steer, speed]` with a comma) becomes `action = -1`, as in deepracer-utils;
its values are in `steering_angle` and `speed`.

`SIM_TRACE_LOG` field counts (facts §7): 15 (2019: ... track_len, tstamp), 16 (+ episode_status),
17 (+ pause_duration), 18 (+ obstacle_crash_counter in simapp 5.3.3; some tools put wall_clock there, so
a value above 1e6 is taken as a wall clock), 19 (+ obstacle_crash_counter, wall_clock).

Garbled input raises `LogFileError` with one line naming the file and the line.
"""

from __future__ import annotations

import json
import math
import os
import re
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from racerlab.logs.files import LogFileError, gunzip, read_bytes

CSV_TO_FRAME = {"X": "x", "Y": "y", "steer": "steering_angle", "throttle": "speed", "all_wheels_on_track": "on_track"}
RAW_COLUMNS = ("episode", "steps", "x", "y", "yaw", "steering_angle", "speed", "action", "reward", "done",
               "on_track", "progress", "closest_waypoint", "track_len", "tstamp", "episode_status",
               "pause_duration", "obstacle_crash_counter", "wall_clock")
_INT_COLUMNS = ("episode", "steps", "closest_waypoint")
_BOOL_COLUMNS = ("done", "on_track")
_OPTIONAL = ("episode_status", "pause_duration", "obstacle_crash_counter", "wall_clock")
_LOG_NAMES = {n: RAW_COLUMNS[:15] + _OPTIONAL[:n - 15] for n in (15, 16, 17, 18, 19)}
_TRACE = re.compile(rb"SIM_TRACE_LOG:([^\n\t\r]*)")
_OLD_CONTINUOUS = re.compile(rb"\[([^\],\n]*),\s*([^\]\n]*)\]")
_INTEGER_ACTION = re.compile(rb"^\s*-?\d+\s*$")
_SNIFF = 4096  # bytes looked at to guess whether `action` is a discrete index
# threads reading and parsing files: more than cores, so that a file waiting on the disk (or a thread
# waiting for a busy core) does not leave a core idle
_THREADS = max(4, os.cpu_count() or 1)
# Arrow memory for parsed logs: the C library's malloc. Arrow's default (mimalloc) touches fresh memory for
# the many small blocks that threads parsing files side by side allocate; in a fresh process that made a
# cold load of 1 M rows cost about half as much CPU again (page zeroing).
MEMORY = pa.system_memory_pool()


# ---------------------------------------------------------------------------------------------------------
# bytes -> Arrow


def _column_types(names, exact: bool = False) -> dict:
    """Arrow types per column: floats, bools, a dictionary for the status and a string `action` (a
    continuous action is a bracketed pair). `exact` reads the integer columns and `action` as int64, which
    parses about twice as fast in a fresh process; `_parse` falls back to the general types when a log
    does not fit (continuous actions, integers written as floats)."""
    types = {}
    for n in names:
        if n == "action":
            types[n] = pa.int64() if exact else pa.string()
        elif n in _BOOL_COLUMNS:
            types[n] = pa.bool_()
        elif n == "episode_status":
            types[n] = pa.dictionary(pa.int32(), pa.string())
        elif exact and n in _INT_COLUMNS:
            types[n] = pa.int64()
        else:
            types[n] = pa.float64()
    return types


def _parse(body, names: list[str], threads: bool) -> pa.Table:
    """CSV text without header (bytes or a buffer), columns `names` (frame names) -> table."""
    if _discrete_actions(body, names):
        try:
            return _read_csv(body, names, threads, _column_types(names, exact=True))
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            pass  # not all integers after all: read it the general way (and name a bad line from there)
    return _read_csv(body, names, threads, _column_types(names))


def _discrete_actions(body, names: list[str]) -> bool:
    """Whether the first line's `action` is a whole number (a discrete action space)."""
    if "action" not in names:
        return False
    fields = bytes(body[:_SNIFF]).split(b"\n", 1)[0].split(b",")
    k = names.index("action")
    return len(fields) == len(names) and bool(_INTEGER_ACTION.match(fields[k]))


def _read_csv(body, names: list[str], threads: bool, types: dict) -> pa.Table:
    return pacsv.read_csv(
        pa.BufferReader(body),
        read_options=pacsv.ReadOptions(column_names=list(names), use_threads=threads, block_size=1 << 24),
        parse_options=pacsv.ParseOptions(newlines_in_values=False),
        convert_options=pacsv.ConvertOptions(column_types=types, true_values=["True", "true"],
                                             false_values=["False", "false"], strings_can_be_null=True),
        memory_pool=MEMORY)


def normalise(table: pa.Table) -> pa.Table:
    """Any parsed table -> exactly `RAW_COLUMNS` with their final types."""
    n = table.num_rows
    cols = []
    for name in RAW_COLUMNS:
        if name in table.column_names:
            col = table.column(name)
        elif name == "episode_status":
            col = pa.nulls(n, pa.dictionary(pa.int32(), pa.string()))
        else:
            col = pa.array(np.full(n, np.nan))
        if name in _INT_COLUMNS:
            col = pc.cast(col, pa.int64())
        elif name == "action":
            col = _action_column(col)
        cols.append(col)
    return pa.table(cols, names=list(RAW_COLUMNS))


def _action_column(col) -> pa.Array:
    """Discrete indices stay; anything else (a continuous "[steer speed]") becomes -1."""
    if pa.types.is_integer(col.type):
        return pc.cast(col, pa.int64())
    if pa.types.is_floating(col.type):
        return pc.cast(col, pa.int64(), safe=False)
    try:
        return pc.cast(col, pa.int64())
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        numeric = pc.match_substring_regex(col, r"^\s*-?\d+\s*$")
        as_int = pc.cast(pc.if_else(numeric, col, "-1"), pa.int64())
        return pc.fill_null(as_int, -1)


def decompress(data: bytes, name: str) -> bytes:
    """A log's bytes as text: gunzipped (bounded, `logs.files.gunzip`) when `name` ends in `.gz`."""
    return gunzip(data, name) if name.endswith(".gz") else data


def split_header(data: bytes, name: str) -> tuple[list[str], bytes]:
    """(frame column names, body) of a simtrace CSV."""
    names, body = _split(data, name)
    return names, bytes(body)


def _split(data: bytes, name: str) -> tuple[list[str], memoryview]:
    """(frame column names, body); the body is a view of `data`, not a copy."""
    end = data.find(b"\n")
    head = (data if end < 0 else data[:end]).decode("utf-8", "replace").strip().lstrip("\ufeff")
    names = [CSV_TO_FRAME.get(h.strip(), h.strip()) for h in head.split(",")]
    missing = [c for c in RAW_COLUMNS[:15] if c not in names and c != "tstamp"]
    if missing:
        raise LogFileError(f"{name}:1: not a simtrace CSV header (missing {', '.join(missing)}): {head[:80]!r}")
    return names, memoryview(data)[len(data) if end < 0 else end + 1:]


def read_simtrace_csv(data: bytes, name: str, threads: bool = False) -> pa.Table:
    """One simtrace CSV (plain or gzip bytes) -> a normalised table."""
    names, body = split_header(decompress(data, name), name)
    return normalise(parse_csv_body(body, names, name, threads))


def parse_csv_body(body, names: list[str], name: str, threads: bool = False, first_line: int = 2) -> pa.Table:
    """CSV text after the header (bytes or a buffer) -> a table of `names`; a bad line is a `LogFileError`."""
    if _blank(body):
        return pa.table({n: pa.array([], t) for n, t in _column_types(names).items()})
    try:
        return _parse(body, names, threads)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as e:
        raise LogFileError(locate_error(bytes(body), names, name, first_line, str(e))) from None


def _blank(body) -> bool:
    head = bytes(body[:_SNIFF])
    return not head.strip() and (len(body) <= _SNIFF or not bytes(body).strip())


def read_simtrace_csvs(blobs: list[tuple[str, bytes]], threads: bool = True) -> tuple[pa.Table, np.ndarray]:
    """Many simtrace CSVs given as (name, plain or gzip bytes) -> (one normalised table, files in the given
    order; the row count of each file). See `read_simtrace_files`."""
    return _read_each([name for name, _ in blobs], lambda i: decompress(blobs[i][1], blobs[i][0]), threads)


def read_simtrace_files(paths: list[str], names_for_messages: list[str], threads: bool = True
                        ) -> tuple[pa.Table, np.ndarray]:
    """Simtrace CSV files on disk (plain or `.gz`) -> (one normalised table, files in the given order; the
    row count of each file). Errors name the file by `names_for_messages`.

    Each file is read and parsed on its own, on a pool of threads when `threads` (reading, gunzip and
    Arrow's parser release the GIL): no copy of all the text into one buffer, no pass counting lines, and
    a busy core holds up one file, not the whole parse. Files whose columns differ (older formats, a
    continuous action read as text) are normalised group by group.
    """
    return _read_each(names_for_messages, lambda i: _read_path(paths[i], names_for_messages[i]), threads)


def _read_path(path: str, name: str) -> bytes:
    return decompress(read_bytes(path, name), name)


def _read_each(names: list[str], plain_text, threads: bool) -> tuple[pa.Table, np.ndarray]:
    def parse(i: int) -> pa.Table:
        columns, body = _split(plain_text(i), names[i])
        return parse_csv_body(body, columns, names[i])

    if threads and len(names) > 1:
        with ThreadPoolExecutor(max_workers=min(len(names), _THREADS)) as pool:
            tables = list(pool.map(parse, range(len(names))))
    else:
        tables = [parse(i) for i in range(len(names))]
    counts = np.array([t.num_rows for t in tables], np.int64)
    groups: dict[pa.Schema, list[int]] = {}
    for i, t in enumerate(tables):
        groups.setdefault(t.schema, []).append(i)
    if len(groups) == 1:
        return normalise(pa.concat_tables(tables)), counts
    # files of several layouts: normalise each layout once, then put the files back in the order given
    pieces: list[pa.Table | None] = [None] * len(tables)
    for members in groups.values():
        table, at = normalise(pa.concat_tables([tables[i] for i in members])), 0
        for i in members:
            pieces[i] = table.slice(at, counts[i])
            at += counts[i]
    return pa.concat_tables(pieces), counts


# ---------------------------------------------------------------------------------------------------------
# finding the bad line


def locate_error(body: bytes, names: list[str], name: str, first_line: int, arrow_msg: str) -> str:
    """One line naming the file, the line number and what is wrong with it."""
    types = _column_types(names)
    labels = {v: k for k, v in CSV_TO_FRAME.items()}  # name the column as the file's header does
    for k, raw in enumerate(body.split(b"\n")):
        if not raw.strip():
            continue
        problem = _line_problem(raw, names, types, labels)
        if problem:
            return f"{name}:{first_line + k}: {problem}: {raw[:100].decode('utf-8', 'replace')!r}"
    return f"{name}: unreadable ({arrow_msg.splitlines()[0] if arrow_msg else 'unknown error'})"


def _line_problem(raw: bytes, names: list[str], types: dict, labels: dict | None = None) -> str | None:
    fields = raw.decode("utf-8", "replace").rstrip("\r").split(",")
    if len(fields) != len(names):
        return f"expected {len(names)} fields, got {len(fields)}"
    for value, col in zip(fields, names, strict=True):
        t = types[col]
        label = (labels or {}).get(col, col)
        if t == pa.float64():
            try:
                float(value)
            except ValueError:
                return f"{label} is not a number ({value!r})"
        elif t == pa.bool_() and value not in ("True", "False", "true", "false"):
            return f"{label} is not True/False ({value!r})"
    return None


# ---------------------------------------------------------------------------------------------------------
# robomaker / simulation logs


def read_sim_trace_log(data: bytes, name: str) -> tuple[pa.Table, dict]:
    """`SIM_TRACE_LOG:` lines of a robomaker / DROA simulation log -> (normalised table, header info).

    Lines may carry `[node]` prefixes or anything before the marker. The header info holds
    `hyperparameters` (the JSON after "Using the following hyper-parameters") when present. A malformed last line
    (a log still being written, cut mid-line) is left out; a malformed line before it is an error.
    """
    lines = _TRACE.findall(data)
    info = {"hyperparameters": _hyperparameters(data)}
    if not lines:
        return normalise(pa.table({})), info
    lines = [line.strip() for line in lines]
    text = b"\n".join(lines)
    if b"[" in text:
        text = _OLD_CONTINUOUS.sub(rb"[\1 \2]", text)
        lines = text.split(b"\n")
    if _cut(lines):
        lines = lines[:-1]
        text = b"\n".join(lines)
    text += b"\n"
    fields = np.fromiter((line.count(b",") + 1 for line in lines), np.int64, len(lines))
    tables = []
    order = []
    for count in np.unique(fields):
        names = _LOG_NAMES.get(int(count))
        where = np.flatnonzero(fields == count)
        if names is None:
            raise LogFileError(_log_line_error(data, name, int(where[0]), f"expected 15 to 19 fields, got {count}"))
        body = text if len(tables) == 0 and where.size == fields.size else _select_lines(text, where)
        try:
            t = _parse(body, list(names), threads=True)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as e:
            k, problem = _bad_line(body, list(names))
            if k is None:
                raise LogFileError(f"{name}: unreadable SIM_TRACE_LOG lines ({str(e).splitlines()[0]})") from None
            raise LogFileError(_log_line_error(data, name, int(where[k]), problem)) from None
        if int(count) == 18 and _looks_like_wall_clock(t.column("obstacle_crash_counter")):
            t = t.rename_columns([*names[:17], "wall_clock"])
        tables.append(normalise(t))
        order.append(where)
    table = pa.concat_tables(tables)
    if len(tables) > 1:
        table = table.take(pa.array(np.argsort(np.concatenate(order), kind="stable")))
    return table, info


def _cut(lines: list[bytes]) -> bool:
    """Whether the last of several SIM_TRACE_LOG lines is a cut one: fewer fields than the line before, or a field
    that does not parse."""
    if len(lines) < 2:
        return False
    count = lines[-1].count(b",") + 1
    names = _LOG_NAMES.get(count)
    if names is None or count != lines[-2].count(b",") + 1:
        return True
    return _line_problem(lines[-1], list(names), _column_types(list(names))) is not None


def _select_lines(text: bytes, where: np.ndarray) -> bytes:
    lines = text.split(b"\n")
    return b"\n".join(lines[i] for i in where) + b"\n"


def _bad_line(body: bytes, names: list[str]) -> tuple[int | None, str]:
    types = _column_types(names)
    labels = {v: k for k, v in CSV_TO_FRAME.items()}
    for k, raw in enumerate(body.split(b"\n")):
        problem = _line_problem(raw, names, types, labels) if raw.strip() else None
        if problem:
            return k, problem
    return None, ""


def _log_line_error(data: bytes, name: str, k: int, problem: str) -> str:
    """Message for the k-th SIM_TRACE_LOG line, with its line number in the file."""
    for i, m in enumerate(_TRACE.finditer(data)):
        if i == k:
            line_no = data.count(b"\n", 0, m.start()) + 1
            return f"{name}:{line_no}: {problem.splitlines()[0]}: {m.group(1)[:100].decode('utf-8', 'replace')!r}"
    return f"{name}: {problem.splitlines()[0]}"


def _looks_like_wall_clock(col) -> bool:
    top = pc.max(pc.abs(col)).as_py()
    return top is not None and top > 1e6


def _hyperparameters(data: bytes) -> dict | None:
    at = data.find(b"Using the following hyper-parameters")
    if at < 0:
        return None
    text = []
    for raw in data[at:at + 20000].split(b"\n")[1:]:
        line = re.sub(r"^\s*(?:\[[^\]]*\]\s+)+", "", raw.decode("utf-8", "replace"))
        text.append(line)
        if "}" in line:
            break
    try:
        return json.loads("".join(text))
    except json.JSONDecodeError:
        return None


# ---------------------------------------------------------------------------------------------------------
# units


def looks_like_radians(yaw: np.ndarray, steer: np.ndarray) -> bool:
    """2019 logs carried radians: |steer| never above 0.6 (30° = 0.52 rad) and |yaw| within pi, while a
    car driving in degrees turns through far more than 3.15° of heading."""
    if yaw.size < 2:
        return False
    yaw_top = float(np.nanmax(np.abs(yaw))) if np.isfinite(yaw).any() else 0.0
    steer_top = float(np.nanmax(np.abs(steer))) if np.isfinite(steer).any() else 0.0
    return 0.0 < yaw_top <= math.pi + 1e-3 and steer_top < 0.6


def to_degrees(table: pa.Table) -> pa.Table:
    for col in ("yaw", "steering_angle"):
        i = table.column_names.index(col)
        table = table.set_column(i, col, pc.multiply(table.column(col), 180.0 / math.pi))
    return table
