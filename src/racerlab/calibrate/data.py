"""Stretches of a real log to replay: a logged state, the actions before it and after it, and where the car went.

A stretch starts at row t of an episode and covers `horizon` steps: its start is row t's front point and heading,
the mean ground speed and yaw rate over the last step (rows t-1, t; the car model works out the speed at row t from
it), or over the last two where the log's steps' lengths are unknown (`racerlab.sim.car.START_STEPS`), and
the wheel angle left unknown (the car model estimates it from the `history` actions of rows t-h..t-1); its
actions are those of rows t..t+horizon-1, its
step lengths the tstamps read by the log's timing rule (`racerlab.sim.car.LOG_TIMING`) and its targets the logged
front points and headings of rows t+1..t+horizon.

Rows are left out where the real simulator did something else than drive: the prepare row (the reset's teleport
falls into it), pause, crash and park rows, gaps in the step count, and steps whose length or position jump is
absurd (an evaluation reset).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import pandas as pd

from racerlab.errors import ConfigError
from racerlab.sim.car import START_STEPS, step_durations

HISTORY = 8  # actions before the start a stretch carries (the delay needs MAX_DELAY_STEPS + 1, the hinge more)
HORIZON = 15  # steps a stretch replays: one second
DRIVING = ("in_progress", "off_track", "lap_complete", "immobilized", "reversed", "time_up")
MIN_STEP_S, MAX_STEP_S = 0.02, 0.2
MAX_STEP_M = 0.5  # farther in one step is a reset, not driving (4 m/s x 0.1 s = 0.4 m)


@dataclass
class Stretches:
    """N stretches in arrays, ready for `racerlab.sim.car.rollout_batch`."""

    start: np.ndarray  # (N, 6) front x, y, heading rad, speed, NaN (wheel angle: estimated), yaw rate rad/s
    commands: np.ndarray  # (N, HISTORY + horizon, 2) steering rad, speed: the history, then the replayed actions
    dts: np.ndarray  # (N, horizon)
    target: np.ndarray  # (N, horizon, 3) logged front x, y, heading (degrees)
    prev: np.ndarray  # (N, 2) the front point one row before the start (the constant-velocity guess)
    prev_dt: np.ndarray  # (N,)
    mean_dt: np.ndarray  # (N,) the time the start's speed and yaw rate are measured over (`START_STEPS`)
    episode: np.ndarray  # (N,) the episode's index in the log (for splits)

    def __len__(self) -> int:
        return len(self.start)

    def take(self, mask) -> Stretches:
        return Stretches(*(getattr(self, f)[mask] for f in self.__dataclass_fields__))


def _episode_stretches(e: pd.DataFrame, horizon: int, every: int, timing: str):
    x = e["x"].to_numpy(float)
    y = e["y"].to_numpy(float)
    yaw = e["yaw"].to_numpy(float)
    steer = np.radians(e["steering_angle"].to_numpy(float))
    speed = e["speed"].to_numpy(float)
    t = e["tstamp"].to_numpy(float)
    steps = e["steps"].to_numpy(float)
    status = e["episode_status"].astype(str).to_numpy() if "episode_status" in e else np.full(len(e), "in_progress")
    n = len(e)
    dt = step_durations(t, timing)  # dt[r]: the step from row r to r + 1 (NaN: unknown)
    jump = np.hypot(np.diff(x), np.diff(y))
    good_step = (np.diff(steps) == 1) & (dt > MIN_STEP_S) & (dt < MAX_STEP_S) & (jump < MAX_STEP_M)
    good_row = np.isin(status, DRIVING)
    good_row[0] = False  # the prepare row
    # step r (row r -> r+1) is usable when both rows are driving rows and the step is sane
    usable = np.zeros(n, dtype=bool)
    usable[:-1] = good_step & good_row[:-1] & good_row[1:]
    ok = np.concatenate([[0], np.cumsum(usable)])  # ok[r] = usable steps before row r
    out = []
    for s in range(HISTORY + 1, n - horizon, every):
        # steps s-1 .. s+horizon-1 all usable, and the history's rows driving rows
        if ok[s + horizon] - ok[s - 1] != horizon + 1 or not good_row[s - HISTORY:s].all():
            continue
        out.append(s)
    if not out:
        return None
    s = np.asarray(out)
    hist = s[:, None] + np.arange(-HISTORY, horizon)[None, :]
    fut = s[:, None] + np.arange(1, horizon + 1)[None, :]
    back = _measured_from(s, ok, START_STEPS[timing])
    span = _between(dt, back, s)
    v0 = _between(jump, back, s) / span
    w0 = np.radians((yaw[s] - yaw[back] + 180.0) % 360.0 - 180.0) / span
    start = np.stack([x[s], y[s], np.radians(yaw[s]), v0, np.full(len(s), np.nan), w0], axis=1)
    commands = np.stack([steer[hist], speed[hist]], axis=2)
    dts = dt[s[:, None] + np.arange(horizon)[None, :]]
    target = np.stack([x[fut], y[fut], yaw[fut]], axis=2)
    prev = np.stack([x[s - 1], y[s - 1]], axis=1)
    return start, commands, dts, target, prev, dt[s - 1], span


def _measured_from(s: np.ndarray, ok: np.ndarray, steps: int) -> np.ndarray:
    """The rows the start's speed and yaw rate are measured from: `steps` rows before each start row of `s` where those
    steps are usable (`ok[r]`: usable steps before row r), else the row before."""
    return np.where(ok[s] - ok[s - steps] == steps, s - steps, s - 1)


def _between(per_step: np.ndarray, back: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The sum of `per_step[r]` (a step's length or distance, row r -> r + 1) over the rows back..s-1 of each start."""
    c = np.concatenate([[0.0], np.cumsum(np.nan_to_num(per_step))])
    return np.where(back == s - 1, per_step[s - 1], c[s] - c[back])  # one step: exactly its own value


def stretches(df: pd.DataFrame, horizon: int = HORIZON, every: int = 1, source: str = "the log",
              timing: str = "previous") -> Stretches:
    """Every `every`-th stretch of `horizon` steps of every episode in a frame of `racerlab.analysis.load`, its steps
    timed by the rule `timing` (`racerlab.sim.car.TIMINGS`; `log_timing(car)` gives a simulator's)."""
    missing = [c for c in ("x", "y", "yaw", "steering_angle", "speed", "tstamp", "steps") if c not in df]
    if missing:
        raise ConfigError(f"{source}: the log has no {missing[0]!r} column; calibrate needs simtrace rows "
                          "(a simtrace folder, a console/DRoA export or a robomaker log)")
    key = "unique_episode" if "unique_episode" in df else "episode"
    parts, eps = [], []
    for k, (_, e) in enumerate(df.groupby(key, sort=True)):
        got = _episode_stretches(e.sort_values("steps"), horizon, every, timing)
        if got is not None:
            parts.append(got)
            eps.append(np.full(len(got[0]), k))
    if not parts:
        raise ConfigError(f"{source}: no episode has {horizon + HISTORY + 2} driven steps in a row to replay; "
                          "give logs of longer episodes")
    cols = [np.concatenate(c) for c in zip(*parts, strict=True)]
    return Stretches(*cols, np.concatenate(eps))


def concat(parts: list[Stretches]) -> Stretches:
    """The stretches of several sets as one (their episode numbers as they are)."""
    return Stretches(*(np.concatenate([getattr(s, f) for s in parts]) for f in Stretches.__dataclass_fields__))


def split(st: Stretches, held_out_every: int = 3, fold: int = 1,
          source: str = "the logs") -> tuple[Stretches, Stretches]:
    """(fit, held out): every `held_out_every`-th episode is held out, from the episode `fold` on (the default: the
    2nd, 5th, ...; folds 0 .. held_out_every - 1 hold out each episode once, for cross-validation). Whole episodes
    only: a stretch overlaps its neighbours by all but one step, so stretches of one episode held out between fit
    ones would be judged on what the fit saw. Too few episodes for that is one line naming `source`."""
    if not 0 <= fold < held_out_every:
        raise ValueError(f"split: fold {fold} is not in 0..{held_out_every - 1}")
    episodes, rank = np.unique(st.episode, return_inverse=True)
    held = (rank % held_out_every) == fold
    if held.all() or not held.any():
        raise ConfigError(f"{source}: {len(episodes)} episode{'' if len(episodes) == 1 else 's'} to replay; the fit is "
                          f"judged on whole episodes it did not see, so it needs {max(fold + 1, 2)} or more: give "
                          "logs of more episodes")
    return st.take(~held), st.take(held)


REPLAYED = ("steps", "x", "y", "yaw", "steering_angle", "speed", "tstamp")  # what makes two episodes the same drive


def drop_copies(df: pd.DataFrame, seen: dict[bytes, str], source: str) -> tuple[pd.DataFrame, list[str]]:
    """`df` without its episodes that repeat, row for row, one seen before (in `seen`: fingerprint -> "episode k of
    LOG", which gains this log's episodes), and a sentence for each copy left out. A copy is no second drive: fitted
    beside its original it only weighs that drive twice, and held out against it it measures the fit on its own
    data (a log given twice, an export that holds one episode fifteen times)."""
    key = "unique_episode" if "unique_episode" in df else "episode"
    cols = [c for c in REPLAYED if c in df]
    if key not in df or not cols:
        return df, []
    keep, notes = [], []
    for ep, e in df.groupby(key, sort=True):
        rows = np.ascontiguousarray(e.sort_values("steps" if "steps" in e else cols[0])[cols].to_numpy(float))
        mark = hashlib.sha1(rows.tobytes()).digest()
        if mark in seen:
            notes.append(f"episode {ep} of {source} repeats {seen[mark]}")
            continue
        seen[mark] = f"episode {ep} of {source}"
        keep.append(ep)
    return (df if not notes else df[df[key].isin(keep)]), notes
