"""Reward re-scoring: a new `reward_function(params)` evaluated on logged steps, with every AWS param
rebuilt from the log and the track, then compared with the logged reward episode by episode.

How each param is rebuilt (facts §1; deepracer-utils' `df_to_params` gets the ones marked * wrong):

- `x`, `y` the logged position (already the model point 0.14 m ahead of the car's base);
  `heading`* = logged yaw and `steering_angle`* = logged steer, both in degrees as logged;
  `speed` = the logged (commanded) speed; `progress`, `steps` as logged (`steps` a float, as in SIM);
- `distance_from_center`, `projection_distance`* (arc length from waypoint 0), `closest_waypoints`*
  (by arc length: next = bisect_right of the waypoints' arc fractions), `is_left_of_center`* and
  `track_width`* (between the border points nearest the centre-line projection) from the track, with
  the same geometry kernels as the simulator;
- `all_wheels_on_track` as logged; `is_offtrack`* / `is_crashed`* where the step's status says so;
- `is_reversed`* per episode: the direction the car drove (its heading against the centre line) unless
  given; `waypoints` and `track_length`* from the track in that direction; `sim_time` = `tstamp`;
- object params empty (no object positions are logged).

Prepare and pause steps are not scored (AWS does not call the reward there; their reward is 0).
The loop building one dict per row and calling the reward is the only Python loop; everything else
is numpy over all rows.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from numba import njit

from racerlab.analysis.episodes import episode_summary, wrap_degrees
from racerlab.reward import (
    MAX_ABS_REWARD,
    as_reward_function,
    check_value,
    describe_exception,
    describe_params,
    error_location,
    return_location,
    source_of,
)
from racerlab.spec import MODEL_POINT_AHEAD_M, NO_OBJECTS, REWARD_PARAM_NAMES, CarParams, ParamsMaker
from racerlab.track import Track
from racerlab.track.kernels import measure_on_track

NOT_SCORED = ("prepare", "pause")
CHUNK_ROWS = 1 << 16  # rows turned into Python lists at a time (keeps memory flat for 10 M-row logs)
MAX_ERROR_DETAILS = 5


# ---------------------------------------------------------------------------------------------------------
# geometry: the track-derived params of many points at once


@njit(cache=True)
def _measure_points(px, py, new_run, center, seg_len, cum_s, inner, outer, wp_ndist, closed, length,
                    driving_ccw, arc, dist, left, width, wprev, wnext, thead):
    """Track params of model points (px, py) with the simulator's kernel (`track.kernels.measure_on_track`).

    `new_run[j]` is True where point j does not follow point j-1 of the same episode (no search hint).
    """
    hint = -1
    for j in range(px.shape[0]):
        if new_run[j]:
            hint = -1
        seg, a, lat, lft, w, prv, nxt, th = measure_on_track(px[j], py[j], center, seg_len, cum_s, inner, outer,
                                                             wp_ndist, closed, length, driving_ccw, hint)
        arc[j] = a
        dist[j] = abs(lat)
        left[j] = lft
        width[j] = w
        wprev[j] = prv
        wnext[j] = nxt
        thead[j] = th
        hint = seg


def track_columns(track: Track, x, y, new_run=None) -> dict[str, np.ndarray]:
    """Params that depend on position and track, for points (x, y) driven in `track`'s direction.

    Returns arrays: projection_distance, distance_from_center, is_left_of_center, track_width,
    prev_waypoint, next_waypoint and track_heading (rad, the centre segment's direction).
    `new_run` (bool per point) marks points that do not continue the previous point's episode.
    """
    px = np.ascontiguousarray(x, dtype=np.float64)
    py = np.ascontiguousarray(y, dtype=np.float64)
    n = px.size
    runs = np.ones(n, np.bool_) if new_run is None else np.ascontiguousarray(new_run, dtype=np.bool_)
    out = {"projection_distance": np.empty(n), "distance_from_center": np.empty(n),
           "is_left_of_center": np.empty(n, np.bool_), "track_width": np.empty(n),
           "prev_waypoint": np.empty(n, np.int64), "next_waypoint": np.empty(n, np.int64),
           "track_heading": np.empty(n)}
    _measure_points(px, py, runs, track.center, track.segment_lengths, track.waypoint_s, track.inner, track.outer,
                    track.waypoint_s / track.length, track.closed, track.length, track.is_ccw, *out.values())
    return out


def infer_reversed(df: pd.DataFrame, track: Track, heading_error=None) -> np.ndarray:
    """Per row: whether its episode drove the track backwards (heading mostly against the centre line)."""
    if heading_error is None:
        heading_error = _heading_error(df, track)
    against = np.cos(np.radians(heading_error)) < 0
    share = pd.Series(against).groupby(df["unique_episode"].to_numpy()).transform("mean").to_numpy()
    return share > 0.5


def _heading_error(df: pd.DataFrame, track: Track) -> np.ndarray:
    cols = track_columns(track, df["x"].to_numpy(), df["y"].to_numpy(), _episode_starts(df))
    return wrap_degrees(df["yaw"].to_numpy() - np.degrees(cols["track_heading"]))


def _episode_starts(df: pd.DataFrame) -> np.ndarray:
    ep = df["unique_episode"].to_numpy()
    start = np.ones(ep.size, bool)
    start[1:] = ep[1:] != ep[:-1]
    return start


# ---------------------------------------------------------------------------------------------------------
# params columns: one array per AWS key


@dataclass
class ParamsColumns:
    """The reward params of many steps as columns; `dict_at(i)` / `score` turn rows into AWS dicts."""

    cols: dict[str, np.ndarray]  # per-row arrays named as the params keys (prev/next waypoint apart)
    reversed: np.ndarray  # bool per row
    forward: Track
    backward: Track

    def __len__(self) -> int:
        return int(self.reversed.size)

    def dict_at(self, i: int) -> dict:
        """The params dict of row i (for error messages and tests)."""
        return next(_dicts(self, np.array([i])))


def params_columns(track: Track, x, y, heading, speed, steering_angle, progress, steps, *, reversed=False,
                   all_wheels_on_track=None, is_offtrack=None, is_crashed=False, sim_time=0.0,
                   new_run=None) -> ParamsColumns:
    """Params for model points (x, y) with heading/steering in degrees; scalars broadcast over rows.

    `all_wheels_on_track` and `is_offtrack` default to the simulator's wheel test: all four wheel centres
    on the road, and none of them.
    """
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    y = np.asarray(y, dtype=np.float64)
    heading = np.broadcast_to(np.asarray(heading, dtype=np.float64), (n,))
    rev = np.broadcast_to(np.asarray(reversed, dtype=bool), (n,)).copy()
    backward = track.reverse()
    geo = _geometry(track, backward, x, y, rev, new_run)
    if all_wheels_on_track is None or is_offtrack is None:
        wheels = wheels_on_track(track, x, y, heading)
        all_wheels_on_track = wheels == 4 if all_wheels_on_track is None else all_wheels_on_track
        is_offtrack = wheels == 0 if is_offtrack is None else is_offtrack
    cols = {"all_wheels_on_track": all_wheels_on_track, "x": x, "y": y, "heading": heading,
            "is_reversed": rev, "progress": progress, "steps": np.asarray(steps, dtype=np.float64),
            "speed": speed, "steering_angle": steering_angle, "is_offtrack": is_offtrack,
            "is_crashed": is_crashed, "sim_time": sim_time, **geo}
    cols = {k: np.broadcast_to(np.asarray(v), (n,)) for k, v in cols.items()}
    return ParamsColumns(cols, rev, track, backward)


def _geometry(forward: Track, backward: Track, x, y, rev, new_run) -> dict[str, np.ndarray]:
    out = None
    for flag, t in ((False, forward), (True, backward)):
        sel = rev == flag
        if not sel.any():
            continue
        part = track_columns(t, x[sel], y[sel], None if new_run is None else np.asarray(new_run)[sel])
        if out is None:
            out = {k: np.empty(x.size, v.dtype) for k, v in part.items()}
        for k, v in part.items():
            out[k][sel] = v
    if out is None:  # no rows
        out = track_columns(forward, x, y)
    return out


def wheels_on_track(track: Track, x, y, heading_deg) -> np.ndarray:
    """How many of the four wheel centres are on the road for model points (x, y) at `heading_deg`."""
    yaw = np.radians(heading_deg)
    c, s = np.cos(yaw), np.sin(yaw)
    bx = np.asarray(x) - MODEL_POINT_AHEAD_M * c
    by = np.asarray(y) - MODEL_POINT_AHEAD_M * s
    count = np.zeros(bx.size, np.int64)
    for ox, oy in CarParams().wheel_offsets():
        pts = np.stack([bx + ox * c - oy * s, by + ox * s + oy * c], axis=1)
        count += track.contains(pts)
    return count


def log_params(df: pd.DataFrame, track: Track, reverse: bool | None = None) -> ParamsColumns:
    """Params of every logged step; `reverse` None infers each episode's direction from its headings."""
    starts = _episode_starts(df)
    if reverse is None:
        rev = infer_reversed(df, track)
    else:
        rev = np.full(len(df), bool(reverse))
    status = df["episode_status"].astype(str).to_numpy() if "episode_status" in df else np.full(len(df), "")
    return params_columns(
        track, df["x"].to_numpy(), df["y"].to_numpy(), df["yaw"].to_numpy(), df["speed"].to_numpy(),
        df["steering_angle"].to_numpy(), df["progress"].to_numpy(), df["steps"].to_numpy(), reversed=rev,
        all_wheels_on_track=df["on_track"].to_numpy(bool), is_offtrack=status == "off_track",
        is_crashed=status == "crashed", sim_time=df["tstamp"].to_numpy(), new_run=starts)


# ---------------------------------------------------------------------------------------------------------
# calling the reward


# every param but the track's length and the object params (no objects are logged) changes from row to row
_MAKE_PARAMS = ParamsMaker(tuple(k for k in REWARD_PARAM_NAMES if k != "track_length" and k not in NO_OBJECTS),
                           parts={"closest_waypoints": 2})
_BUILT_HERE = ("waypoints", "closest_waypoints")  # not columns: made from the direction and the waypoint pair


def _dicts(pc: ParamsColumns, idx: np.ndarray):
    """Yield the AWS params dict of each row in `idx` (a fresh dict and fresh lists per call)."""
    c = pc.cols
    cols = {k: np.asarray(c[k][idx]).tolist() for k in _MAKE_PARAMS.per_row if k not in _BUILT_HERE}
    wps = (pc.forward.waypoints, pc.backward.waypoints)
    cols["waypoints"] = [wps[r] for r in cols["is_reversed"]]
    cols["closest_waypoints"] = (c["prev_waypoint"][idx].tolist(), c["next_waypoint"][idx].tolist())
    return _MAKE_PARAMS(cols, {"track_length": pc.forward.length, **NO_OBJECTS})


@dataclass
class RewardProblem:
    """One kind of failure (same message and place) seen `count` times; `params` of the first one."""

    message: str
    row: int
    params: dict
    count: int = 1
    label: str = "row"  # what `row` counts: log rows, sampled states, ...

    def describe(self) -> str:
        times = f" ({self.count} times)" if self.count > 1 else ""
        return f"{self.message}{times}, first at {self.label} {self.row}\n  params: {describe_params(self.params)}"


@dataclass
class ScoreResult:
    rewards: np.ndarray  # NaN where the reward failed or the row was not scored
    problems: list[RewardProblem] = field(default_factory=list)  # distinct failures, first seen first
    failed: int = 0  # rows whose reward raised or was not a finite number within ±1e5
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.failed == 0


class _Problems:
    def __init__(self, source: Path | None, limit: int):
        self.source = source
        self.limit = limit
        self.by_key: dict[str, RewardProblem] = {}
        self.where: dict[str, str] = {}
        self.failed = 0

    def add(self, message: str, row: int, params: dict) -> None:
        self.failed += 1
        p = self.by_key.get(message)
        if p is not None:
            p.count += 1
        elif len(self.by_key) < self.limit:
            self.by_key[message] = RewardProblem(message, row, params)

    def exception(self, exc: BaseException, row: int, params: dict) -> None:
        where = error_location(exc, self.source) or str(self.source or "reward_function")
        self.add(f"{where}: {describe_exception(exc, params)}", row, params)

    def value(self, fn, r, row: int, params: dict) -> float:
        """The reward as a float, or NaN after recording why `check_value` refuses it."""
        r, what = check_value(r)
        if what is None:
            return r
        if what not in self.where:  # find the `return` line once per kind of bad value
            self.where[what] = return_location(fn, params) or str(self.source or "reward_function")
        self.add(f"{self.where[what]}: reward_function {what}", row, params)
        return math.nan


def score(fn, pc: ParamsColumns, rows=None, *, max_problems: int = MAX_ERROR_DETAILS) -> ScoreResult:
    """Call `fn` on the params of `rows` (all by default); failures are collected, never raised.

    Distinct failures (message and place) are kept up to `max_problems`, each with the params of its first
    occurrence; failing rows get NaN.
    """
    t0 = time.perf_counter()
    problems = _Problems(source_of(fn), max_problems)
    out = np.full(len(pc), np.nan)
    idx = np.arange(len(pc)) if rows is None else np.flatnonzero(rows) if np.asarray(rows).dtype == bool \
        else np.asarray(rows, np.int64)
    for lo in range(0, idx.size, CHUNK_ROWS):
        part = idx[lo:lo + CHUNK_ROWS]
        vals = np.empty(part.size)
        for j, (row, params) in enumerate(zip(part.tolist(), _dicts(pc, part), strict=True)):
            try:
                r = fn(params)
            except Exception as exc:  # noqa: BLE001 - the user's reward failed: record it with its params
                problems.exception(exc, row, params)
                r = math.nan
            else:
                if type(r) is not float or not -MAX_ABS_REWARD <= r <= MAX_ABS_REWARD:
                    r = problems.value(fn, r, row, params)
            vals[j] = r
        out[part] = vals
    return ScoreResult(out, list(problems.by_key.values()), problems.failed, time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------------------
# re-scoring a log and comparing


@dataclass
class RescoreResult:
    new_reward: np.ndarray  # per row; 0 on prepare/pause steps, NaN where the new reward failed
    problems: list[RewardProblem]
    failed: int
    reversed_episodes: int
    seconds: float  # total: params + reward calls
    reward_seconds: float  # the reward calls alone

    @property
    def ok(self) -> bool:
        return self.failed == 0


def rescore(df: pd.DataFrame, reward, track: Track, *, reverse: bool | None = None) -> RescoreResult:
    """Evaluate `reward` (a callable or a path to a reward_function.py) on every logged step of `df`.

    Rows are taken in episode and step order, so a reward function that keeps state between calls sees
    them as the simulator did.
    """
    fn = as_reward_function(reward)
    t0 = time.perf_counter()
    pc = log_params(df, track, reverse)
    status = df["episode_status"].astype(str).to_numpy() if "episode_status" in df else np.full(len(df), "")
    scored = ~np.isin(status, NOT_SCORED)
    res = score(fn, pc, scored)
    new = np.where(scored, res.rewards, 0.0)
    ep = df["unique_episode"].to_numpy()
    rev_eps = int(np.unique(ep[pc.reversed]).size)
    return RescoreResult(new, res.problems, res.failed, rev_eps, time.perf_counter() - t0, res.seconds)


def compare(df: pd.DataFrame, new_reward) -> pd.DataFrame:
    """Per episode: outcome, progress, time, lap time, the logged `reward` and the `new_reward` totals.

    Rows whose new reward failed (NaN) make that episode's `new_reward` NaN.
    """
    eps = episode_summary(df)
    new = pd.Series(np.asarray(new_reward, dtype=np.float64)).groupby(df["unique_episode"].to_numpy()).sum(
        min_count=1)
    nan_eps = pd.Series(np.isnan(new_reward)).groupby(df["unique_episode"].to_numpy()).any()
    eps["new_reward"] = new.where(~nan_eps).reindex(eps.index).to_numpy()
    keep = ["iteration", "episode", "outcome", "complete", "steps", "progress", "time", "lap_time", "reward",
            "new_reward"]
    return eps[[c for c in keep if c in eps.columns]]


def correlations(cmp: pd.DataFrame) -> pd.DataFrame:
    """Spearman rank correlations of the old and new episode rewards with lap time (complete laps) and
    with progress (all episodes). A good reward ranks faster laps higher: a negative lap-time correlation."""
    laps = cmp[cmp["complete"]]
    rows = []
    for col in ("reward", "new_reward"):
        rows.append({"reward": col,
                     "vs lap time (complete laps)": _spearman(laps[col], laps["lap_time"]),
                     "vs progress (all episodes)": _spearman(cmp[col], cmp["progress"]),
                     "laps": len(laps), "episodes": len(cmp)})
    return pd.DataFrame(rows).set_index("reward")


def _spearman(a: pd.Series, b: pd.Series) -> float:
    ok = a.notna() & b.notna()
    if ok.sum() < 3 or a[ok].nunique() < 2 or b[ok].nunique() < 2:
        return math.nan
    return float(a[ok].rank().corr(b[ok].rank()))


__all__ = ["MAX_ABS_REWARD", "ParamsColumns", "RescoreResult", "RewardProblem", "ScoreResult", "compare",
           "correlations", "infer_reversed", "log_params", "params_columns", "rescore", "score", "track_columns",
           "wheels_on_track", "wrap_degrees"]
