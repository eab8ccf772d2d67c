"""Writing simtrace CSVs exactly as the AWS simulator formats them (facts §7), without per-row Python.

Each column is turned into a right-aligned byte matrix with NUL padding; the columns are laid side by
side with commas, and dropping the NUL bytes leaves the CSV text. Fixed-point columns (`%.4f`, `%.2f`)
are rounded in integer arithmetic; the rare value that lies within rounding noise of a tie (or is
non-finite or huge) is formatted by Python's `%` so the text is always identical to `"%.4f" % x`.

Formats: episode %d, steps %d, X %.4f, Y %.4f, yaw %.4f, steer %.2f, throttle %.2f, action %d or
"[steer speed]" (each %.2f), reward %.4f, done True/False, all_wheels_on_track True/False, progress %.4f,
closest_waypoint %d, track_len %.2f, tstamp `str(round(t, 3))` (sim time on Gazebo's 1 ms clock, e.g.
`36.597`), episode_status %s, pause_duration %.2f, obstacle_crash_counter %d, wall_clock %.4f.
"""

from __future__ import annotations

import gzip
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from racerlab.logs.atomic import commit_temp, temp_path_for

SIMTRACE_COLUMNS = ("episode", "steps", "X", "Y", "yaw", "steer", "throttle", "action", "reward", "done",
                    "all_wheels_on_track", "progress", "closest_waypoint", "track_len", "tstamp",
                    "episode_status", "pause_duration", "obstacle_crash_counter", "wall_clock")
HEADER = ",".join(SIMTRACE_COLUMNS) + "\n"

_INT = "int"
_BOOL = "bool"
_STR = "str"
_TSTAMP = "tstamp"
_ACTION = "action"
# column -> kind, where a kind that is an int means "%.<kind>f"
COLUMN_FORMATS = {"episode": _INT, "steps": _INT, "X": 4, "Y": 4, "yaw": 4, "steer": 2, "throttle": 2,
                  "action": _ACTION, "reward": 4, "done": _BOOL, "all_wheels_on_track": _BOOL, "progress": 4,
                  "closest_waypoint": _INT, "track_len": 2, "tstamp": _TSTAMP, "episode_status": _STR,
                  "pause_duration": 2, "obstacle_crash_counter": _INT, "wall_clock": 4}
_CHUNK_ROWS = 65536


# ---------------------------------------------------------------------------------------------------------
# reference formatting (one row in Python): the definition the vectorised code must match


def format_value(column: str, value) -> str:
    """One value formatted as AWS does (slow; for tests and the rare ambiguous value).

    printf-style on purpose: the simulator formats with `%` and `"%d" % 3.7` truncates where `{:d}` fails.
    """
    kind = COLUMN_FORMATS[column]
    if kind == _INT:
        return "%d" % value  # noqa: UP031
    if kind == _BOOL:
        return "True" if bool(value) else "False"
    if kind == _STR:
        return str(value)
    if kind == _TSTAMP:
        return str(round(float(value), 3))
    if kind == _ACTION:
        if np.ndim(value) == 1:
            return "[%.2f %.2f]" % (float(value[0]), float(value[1]))  # noqa: UP031
        return "%d" % value  # noqa: UP031
    return "%.*f" % (kind, float(value))  # noqa: UP031


def format_row(row: Mapping) -> str:
    """One CSV line (with newline) from a mapping of the 19 columns to scalars."""
    return ",".join(format_value(c, row[c]) for c in SIMTRACE_COLUMNS) + "\n"


# ---------------------------------------------------------------------------------------------------------
# vectorised formatting


def _digits(values: np.ndarray, min_width: int = 1, zero_pad: bool = False) -> np.ndarray:
    """Non-negative int64 [n] -> uint8 [n, w] ASCII digits, right-aligned; leading zeros become NUL
    padding unless `zero_pad`."""
    n = values.shape[0]
    top = int(values.max()) if n else 0
    width = max(min_width, len(str(top)))
    powers = 10 ** np.arange(width - 1, -1, -1, dtype=np.int64)
    out = ((values[:, None] // powers) % 10 + 48).astype(np.uint8)
    if not zero_pad:
        out[(values[:, None] < powers) & (np.arange(width) < width - 1)] = 0
    return out


def _prepend(sign: np.ndarray, body: np.ndarray, char: str) -> np.ndarray:
    """Put `char` just before the first non-NUL byte of rows where `sign`, widening by one column."""
    out = np.zeros((body.shape[0], body.shape[1] + 1), np.uint8)
    out[:, 1:] = body
    if sign.any():
        first = np.argmax(body != 0, axis=1)  # index in body; the byte before it in `out` is `first`
        rows = np.nonzero(sign)[0]
        out[rows, first[rows]] = ord(char)
    return out


def _format_ints(values) -> np.ndarray:
    v = np.asarray(values)
    if v.dtype.kind == "f":
        if not np.isfinite(v).all():
            raise ValueError("an integer simtrace column holds a non-finite value")
        v = np.trunc(v)  # "%d" % 3.7 == "3"
    v = v.astype(np.int64)
    return _prepend(v < 0, _digits(np.abs(v)), "-")


def _format_fixed(values, decimals: int) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64)
    scale = 10.0 ** decimals
    scaled = np.abs(x) * scale
    ok = np.isfinite(scaled) & (scaled < 2.0 ** 52)
    safe = np.where(ok, scaled, 0.0)
    q = np.rint(safe)
    # within float noise of a .5 tie, only the exact binary value decides: let Python's "%" do those
    ambiguous = ok & (np.abs(safe - np.floor(safe) - 0.5) <= safe * 1e-15)
    whole, part = np.divmod(q.astype(np.int64), np.int64(10 ** decimals))
    body = np.concatenate([_digits(whole), np.full((len(x), 1), ord("."), np.uint8),
                           _digits(part, decimals, zero_pad=True)], axis=1)
    out = _prepend(np.signbit(x), body, "-")
    slow = np.nonzero(~ok | ambiguous)[0]
    if slow.size:
        out = _patch(out, slow, ["%.*f" % (decimals, x[i]) for i in slow])  # noqa: UP031
    return out


def _patch(mat: np.ndarray, rows: np.ndarray, texts: list[str]) -> np.ndarray:
    """Replace the given rows of a byte matrix by `texts` (right-aligned), widening when needed."""
    width = max(mat.shape[1], max(len(t) for t in texts))
    if width > mat.shape[1]:
        wide = np.zeros((mat.shape[0], width), np.uint8)
        wide[:, width - mat.shape[1]:] = mat
        mat = wide
    for r, t in zip(rows, texts, strict=True):
        mat[r] = 0
        mat[r, width - len(t):] = np.frombuffer(t.encode("ascii"), np.uint8)
    return mat


def _format_table(labels: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Rows from a small table of strings: labels [k] (str), codes [n] indexes into labels."""
    encoded = [str(s).encode("utf-8") for s in labels]
    width = max(1, max((len(e) for e in encoded), default=1))
    table = np.zeros((len(encoded), width), np.uint8)
    for i, e in enumerate(encoded):
        if b"," in e or b"\n" in e or b"\0" in e:
            raise ValueError(f"simtrace text value {e!r} contains a comma, newline or NUL")
        table[i, width - len(e):] = np.frombuffer(e, np.uint8)
    return table[codes]


def _format_bools(values) -> np.ndarray:
    return _format_table(np.array(["False", "True"]), np.asarray(values).astype(bool).astype(np.intp))


def _format_strings(values) -> np.ndarray:
    labels, codes = np.unique(np.asarray(values).astype(str), return_inverse=True)
    return _format_table(labels, codes.reshape(-1))


def _format_tstamp(values) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64)
    # str(round(t, 3)) == "%.3f" % t without trailing zeros, one decimal kept ("36.5", "36.0")
    ms = _format_fixed(x, 3)
    strip = (ms[:, -1] == ord("0")) & (ms[:, -2] != ord("."))
    ms[strip, -1] = 0
    strip &= (ms[:, -2] == ord("0")) & (ms[:, -3] != ord("."))
    ms[strip, -2] = 0
    huge = ~np.isfinite(x) | (np.abs(x) >= 1e16)
    if huge.any():
        rows = np.nonzero(huge)[0]
        ms = _patch(ms, rows, [str(round(float(x[i]), 3)) for i in rows])
    return ms


def _format_action(values) -> np.ndarray:
    a = np.asarray(values)
    if a.ndim == 1:
        return _format_ints(a)
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"action must be [n] indices or [n, 2] (steer, speed), got shape {a.shape}")
    n = a.shape[0]
    parts = [np.full((n, 1), ord("["), np.uint8), _format_fixed(a[:, 0], 2), np.full((n, 1), ord(" "), np.uint8),
             _format_fixed(a[:, 1], 2), np.full((n, 1), ord("]"), np.uint8)]
    return np.concatenate(parts, axis=1)  # NUL padding inside a cell is dropped with all the others


_FORMATTERS = {_INT: _format_ints, _BOOL: _format_bools, _STR: _format_strings, _TSTAMP: _format_tstamp,
               _ACTION: _format_action}


def _column_bytes(column: str, values) -> np.ndarray:
    kind = COLUMN_FORMATS[column]
    if isinstance(kind, int):
        return _format_fixed(values, kind)
    return _FORMATTERS[kind](values)


def _check_columns(columns: Mapping) -> int:
    missing = [c for c in SIMTRACE_COLUMNS if c not in columns]
    extra = [c for c in columns if c not in COLUMN_FORMATS]
    if missing or extra:
        raise ValueError(f"simtrace columns: missing {missing}, unknown {extra}")
    lengths = {c: len(columns[c]) for c in SIMTRACE_COLUMNS}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"simtrace columns differ in length: {lengths}")
    return lengths["episode"]


def format_rows(columns: Mapping[str, np.ndarray | list]) -> bytes:
    """The CSV lines (no header) for a batch of rows given as the 19 columns."""
    n = _check_columns(columns)
    if n == 0:
        return b""
    chunks = []
    for start in range(0, n, _CHUNK_ROWS):
        stop = min(n, start + _CHUNK_ROWS)
        blocks = []
        for i, c in enumerate(SIMTRACE_COLUMNS):
            if i:
                blocks.append(np.full((stop - start, 1), ord(","), np.uint8))
            blocks.append(_column_bytes(c, _slice(columns[c], start, stop)))
        blocks.append(np.full((stop - start, 1), ord("\n"), np.uint8))
        mat = np.concatenate(blocks, axis=1)
        chunks.append(mat[mat != 0].tobytes())
    return b"".join(chunks)


def _slice(values, start: int, stop: int):
    if isinstance(values, np.ndarray):
        return values[start:stop]
    return np.asarray(values[start:stop]) if not isinstance(values, list) else values[start:stop]


# ---------------------------------------------------------------------------------------------------------
# the writer


class SimtraceWriter:
    """Appends simtrace rows to `path` and publishes the file atomically on `close()`.

    Rows go to a hidden temporary file next to `path`; `close()` flushes, fsyncs and renames it to
    `path`, so a crash never leaves a half file under the final name (the temporary file is removed by
    `abort()`, by leaving a `with` block with an exception, or later by `remove_stale_temps`). The header
    is written once, also when no row was written.

    `compress=True` gzips the file and appends `.gz` to `path` when missing (racerlab's reader reads it;
    deepracer-utils 1.5.6 does not). `sample_episodes=k` keeps only rows whose `episode % k == 0`
    (bounded logs that stay plain CSV; deepracer-utils then loads them, but its `unique_episode`
    arithmetic assumes every episode is present — racerlab's reader does not).
    """

    def __init__(self, path: str | os.PathLike, compress: bool = False, *, sample_episodes: int = 1,
                 compresslevel: int = 3):
        path = Path(path)
        if compress and path.suffix != ".gz":
            path = path.with_name(path.name + ".gz")
        if sample_episodes < 1:
            raise ValueError(f"sample_episodes must be >= 1, got {sample_episodes}")
        self.path = path
        self.compress = compress
        self.sample_episodes = int(sample_episodes)
        self.rows = 0
        path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = temp_path_for(path)
        self._raw = open(self._tmp, "wb")
        self._out = gzip.GzipFile(fileobj=self._raw, mode="wb", compresslevel=compresslevel, mtime=0) \
            if compress else self._raw
        self._out.write(HEADER.encode("ascii"))
        self._closed = False

    def write(self, columns: Mapping[str, np.ndarray | list]) -> int:
        """Append a batch of rows given as the 19 columns of equal length; returns the rows written."""
        if self._closed:
            raise ValueError(f"simtrace writer for {self.path} is closed")
        _check_columns(columns)
        if self.sample_episodes > 1:
            keep = np.asarray(columns["episode"]) % self.sample_episodes == 0
            columns = {c: np.asarray(v)[keep] for c, v in columns.items()}
        data = format_rows(columns)
        try:
            self._out.write(data)
        except OSError as exc:  # a full disk: no half file stays behind, and the error names the file
            self.abort()
            raise _named(exc, self.path) from exc
        written = len(columns["episode"])
        self.rows += written
        return written

    def close(self) -> Path:
        """Finish the file and move it to its final name; returns that path."""
        if self._closed:
            return self.path
        try:
            if self._out is not self._raw:
                self._out.close()
            self._raw.flush()
            os.fsync(self._raw.fileno())
            self._raw.close()
            self._closed = True
            return commit_temp(self._tmp, self.path)
        except OSError as exc:  # a full disk: no half file stays behind, and the error names the file
            self._closed = False
            self.abort()
            raise _named(exc, self.path) from exc

    def abort(self) -> None:
        """Discard what was written; the final file is not created (or left as it was)."""
        if not self._closed:
            self._closed = True
            try:
                for f in (self._out, self._raw):
                    try:
                        f.close()
                    except OSError:  # the disk that is full cannot take the last buffered bytes either
                        pass
            finally:
                self._tmp.unlink(missing_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _named(exc: OSError, path: Path) -> OSError:
    return exc if exc.filename else OSError(exc.errno, exc.strerror, str(path))


def write_simtrace(path: str | os.PathLike, columns: Mapping[str, np.ndarray | list], compress: bool = False) -> Path:
    """Write one whole simtrace file atomically (header + rows)."""
    with SimtraceWriter(path, compress) as w:
        w.write(columns)
    return w.path
