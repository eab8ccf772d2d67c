"""Aggregations of a step frame (`racerlab.analysis.load`): per step kinematics, per episode, per iteration.

- `step_kinematics(df)`: true speed from positions and time, direction of travel and slide (heading minus
  direction of travel), per step.
- `episode_summary(df)`: one row per episode (outcome, start waypoint, steps, time, progress, reward, lap
  time, distance, true and commanded speeds, slide).
- `iteration_summary(episodes, training_metrics, jsonl)`: one row per iteration (reward mean/std, completion
  rate, lap-time statistics, training vs in-training evaluation completion from TrainingMetrics.json,
  entropy and KL from racerlab's metrics.jsonl).

Everything is vectorised over rows (groupby / reduceat on the episode-sorted frame), no Python loop
over episodes.

A lap is complete when its episode ends with `lap_complete` or at progress 100, as AWS's EvalMetrics and
deepracer-utils count it: in a continuous (multi-lap) evaluation every lap but the trial's last ends at
progress 100 with status `in_progress` (done False), and the `episode` column counts the laps, so each lap
is an episode of its own.

Time of an episode: last `tstamp` minus first plus one step (1/15 s), because the first row is logged
after the prepare step (for the later laps of a continuous evaluation: after the previous lap's last
step). This equals TrainingMetrics' `elapsed_time_in_milliseconds` and racerlab's lap time;
deepracer-utils' `time` is one step shorter.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from racerlab.spec import STEP_S

MIN_MOVE_M = 1e-3  # below this a step's direction of travel is undefined (positions are logged to 0.1 mm)


def _episode_bounds(df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Row index of each episode's first row, and a bool per row: first row of its episode."""
    ep = df["unique_episode"].to_numpy()
    first = np.ones(ep.size, bool)
    first[1:] = ep[1:] != ep[:-1]
    return np.flatnonzero(first), first


def wrap_degrees(a):
    """Angles in degrees wrapped to [-180, 180)."""
    return (np.asarray(a, dtype=np.float64) + 180.0) % 360.0 - 180.0


def step_kinematics(df: pd.DataFrame) -> pd.DataFrame:
    """Per step (same index as `df`), from the logged model-point positions and timestamps:

    step_distance (m moved since the previous row), step_time (s), true_speed (m/s), bearing (direction of
    travel, degrees) and slide (heading minus bearing, degrees in [-180, 180)). All NaN on an episode's first
    row; bearing and slide also NaN where the car moved less than 1 mm.

    Direction of travel is that of the model point, 0.14 m ahead of the base, so a car turning on perfect grip
    shows a few degrees of slide too; the grip limit of the car model shows as much larger values.
    """
    _, first = _episode_bounds(df)
    x, y = df["x"].to_numpy(), df["y"].to_numpy()
    dx = np.diff(x, prepend=np.nan)
    dy = np.diff(y, prepend=np.nan)
    dt = np.diff(df["tstamp"].to_numpy(), prepend=np.nan)
    dx[first] = dy[first] = dt[first] = np.nan
    dist = np.hypot(dx, dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = np.where(dt > 0, dist / dt, np.nan)
    moved = dist >= MIN_MOVE_M
    bearing = np.where(moved, np.degrees(np.arctan2(dy, dx)), np.nan)
    yaw = df["yaw"].to_numpy()
    # heading during the step: halfway between the headings logged at its two ends
    prev_yaw = np.roll(yaw, 1)
    mid = prev_yaw + 0.5 * wrap_degrees(yaw - prev_yaw)
    slide = wrap_degrees(mid - bearing)
    return pd.DataFrame({"step_distance": dist, "step_time": dt, "true_speed": speed, "bearing": bearing,
                         "slide": slide}, index=df.index)


def _step_time(df: pd.DataFrame) -> float:
    dt = np.diff(df["tstamp"].to_numpy()[:10_000])
    dt = dt[dt > 0]
    return float(np.median(dt)) if dt.size else STEP_S


def episode_summary(df: pd.DataFrame, kinematics: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per episode, indexed by `unique_episode`.

    Columns: iteration, worker, episode (stream for evaluations), outcome (last episode_status; lap_complete for
    a lap that ended at progress 100 inside a continuous evaluation), complete,
    start_waypoint (closest waypoint of the first row), start_progress, steps (last step number), time (s),
    progress (last, as AWS's completion), max_progress, reward (sum), lap_time (time of complete laps),
    time_if_complete (time * 100 / progress), reward_if_complete, distance (m), true_speed (distance / time),
    max_true_speed, speed (mean commanded), mean_abs_slide and max_abs_slide (degrees), off_track and
    crashed (counts of such steps, meaningful for evaluations with resets).
    """
    kin = step_kinematics(df) if kinematics is None else kinematics
    starts, _ = _episode_bounds(df)
    ends = np.append(starts[1:], len(df)) - 1
    idx = df["unique_episode"].to_numpy()[starts]
    col = {c: df[c].to_numpy() for c in ("steps", "progress", "reward", "tstamp", "speed", "closest_waypoint")}
    status = df["episode_status"].astype(str).to_numpy() if "episode_status" in df else np.full(len(df), "")
    out = {k: df[k].to_numpy()[starts] for k in ("iteration", "worker", "stream", "episode") if k in df}
    out["complete"] = (status[ends] == "lap_complete") | (col["progress"][ends] >= 100.0)
    out["outcome"] = np.where(out["complete"], "lap_complete", status[ends])
    out["start_waypoint"] = col["closest_waypoint"][starts]
    out["start_progress"] = col["progress"][starts]
    out["steps"] = col["steps"][ends]
    out["time"] = col["tstamp"][ends] - col["tstamp"][starts] + _step_time(df)
    out["progress"] = col["progress"][ends]
    out["max_progress"] = np.maximum.reduceat(col["progress"], starts) if len(df) else np.zeros(0)
    out["reward"] = np.add.reduceat(col["reward"], starts) if len(df) else np.zeros(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out["lap_time"] = np.where(out["complete"], out["time"], np.nan)
        scale = np.where(out["progress"] > 0, 100.0 / out["progress"], np.nan)
    out["time_if_complete"] = out["time"] * scale
    out["reward_if_complete"] = out["reward"] * scale
    eps = pd.DataFrame(out, index=pd.Index(idx, name="unique_episode"))
    per = pd.DataFrame({"d": np.nan_to_num(kin["step_distance"].to_numpy()), "v": kin["true_speed"].to_numpy(),
                        "s": np.abs(kin["slide"].to_numpy()), "cmd": col["speed"],
                        "off": status == "off_track", "crash": status == "crashed"}).groupby(
        df["unique_episode"].to_numpy())
    agg = per.agg(distance=("d", "sum"), max_true_speed=("v", "max"), speed=("cmd", "mean"),
                  mean_abs_slide=("s", "mean"), max_abs_slide=("s", "max"), off_track=("off", "sum"),
                  crashed=("crash", "sum"))
    eps = eps.join(agg)
    with np.errstate(invalid="ignore", divide="ignore"):
        eps.insert(eps.columns.get_loc("max_true_speed"), "true_speed", eps["distance"] / eps["time"])
    return eps


# ---------------------------------------------------------------------------------------------------------
# per iteration


def run_metrics(path: str | os.PathLike) -> tuple[pd.DataFrame | None, list[dict]]:
    """TrainingMetrics (all workers, as `load_metrics` reads them) and racerlab's metrics.jsonl entries of
    a model folder; None / [] where a folder has none."""
    from racerlab.analysis.load import load_metrics
    from racerlab.logs import LogFileError, read_metrics_jsonl

    path = Path(path)
    if not path.is_dir():
        return None, []
    try:
        tm = load_metrics(path, "training")
    except LogFileError:
        tm = None
    jsonl = read_metrics_jsonl(path / "metrics" / "metrics.jsonl")
    return tm, jsonl


def iteration_summary(episodes: pd.DataFrame, training_metrics: pd.DataFrame | None = None,
                      jsonl: list[dict] | None = None) -> pd.DataFrame:
    """One row per iteration (0-based, as the simtrace files number them).

    From the episodes: episodes, reward_mean, reward_std, progress_mean, progress_std, time_mean,
    completion_rate (share of complete laps), laps, lap_time_min / lap_time_p25 / lap_time_mean.
    From TrainingMetrics.json: train_completion and eval_completion (mean completion_percentage of the
    training and of the in-training evaluation episodes), eval_lap_rate, eval_lap_time_min.
    From metrics.jsonl (racerlab; its iteration 1 wrote 0-iteration.csv): entropy, approx_kl, learning_rate,
    env_steps_per_s, explained_variance, eval_best_lap, and the learner's diagnostics where the run wrote them
    (`agent.ppo`: value_rmse, advantage_std, return_scale, action_std_steer, action_std_speed).
    """
    g = episodes.groupby("iteration")
    laps = episodes["lap_time"]
    out = pd.DataFrame({
        "episodes": g.size(),
        "reward_mean": g["reward"].mean(), "reward_std": g["reward"].std(ddof=0),
        "progress_mean": g["progress"].mean(), "progress_std": g["progress"].std(ddof=0),
        "time_mean": g["time"].mean(),
        "completion_rate": g["complete"].mean(), "laps": g["complete"].sum(),
        "lap_time_min": laps.groupby(episodes["iteration"]).min(),
        "lap_time_p25": laps.groupby(episodes["iteration"]).quantile(0.25),
        "lap_time_mean": laps.groupby(episodes["iteration"]).mean(),
    })
    if training_metrics is not None and len(training_metrics):
        out = out.join(_phase_columns(training_metrics), how="outer")
    if jsonl:
        out = out.join(_jsonl_columns(jsonl), how="left")
    out.index.name = "iteration"
    return out


def _phase_columns(tm: pd.DataFrame) -> pd.DataFrame:
    lap = tm["episode_status"].astype(str).str.lower().eq("lap complete")
    tm = tm.assign(_lap=lap, _lap_time=np.where(lap, tm["elapsed_time_in_milliseconds"] / 1000.0, np.nan))
    train = tm[tm["phase"] == "training"].groupby("iteration")
    ev = tm[tm["phase"] == "evaluation"].groupby("iteration")
    return pd.DataFrame({
        "train_completion": train["completion_percentage"].mean(),
        "eval_completion": ev["completion_percentage"].mean(),
        "eval_lap_rate": ev["_lap"].mean(),
        "eval_lap_time_min": ev["_lap_time"].min(),
    })


_JSONL_KEYS = {"entropy": "losses/entropy", "approx_kl": "losses/approx_kl", "learning_rate": "lr",
               "env_steps_per_s": "charts/env_steps_per_s", "explained_variance": "losses/explained_variance",
               "value_rmse": "learner/value_rmse", "advantage_std": "learner/advantage_std",
               "return_scale": "learner/return_scale", "action_std_steer": "learner/action_std_0",
               "action_std_speed": "learner/action_std_1", "eval_best_lap": "eval/best_lap"}


def _jsonl_columns(entries: list[dict]) -> pd.DataFrame:
    rows = {int(e["iteration"]) - 1: {k: e.get(src) for k, src in _JSONL_KEYS.items()}
            for e in entries if "iteration" in e}
    return pd.DataFrame.from_dict(rows, orient="index", columns=list(_JSONL_KEYS)).astype(float)


__all__ = ["episode_summary", "iteration_summary", "run_metrics", "step_kinematics", "wrap_degrees"]
