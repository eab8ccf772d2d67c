"""Re-scoring 1 M logged steps with a new reward, and the aggregations and heatmap of the analysis report, on a
training-like log driven along a real AWS track. One JSON line per measurement.

Budget (DESIGN.md): re-score 1 M rows with a new reward <= 20 s; deepracer-utils' `new_reward` took ~36 s per
100 k rows on this machine (~6 min per 1 M, reference/analysis_and_racing_line_tools.md).

    python benchmarks/rescore_speed.py [--rows 1000000] [--track PATH] [--reward FILE]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from racerlab import track as tracks
from racerlab.analysis import load
from racerlab.analysis.episodes import episode_summary, iteration_summary, step_kinematics
from racerlab.analysis.plots import cell_statistic
from racerlab.analysis.rescore import compare, log_params, rescore, score
from racerlab.logs.layout import training_simtrace_path
from racerlab.logs.simtrace import SimtraceWriter
from racerlab.reward import EXAMPLE_REWARD, load_reward_function
from racerlab.spec import STEP_S

REPO = Path(__file__).resolve().parents[1]
DEFAULT_TRACK = REPO.parent / "shared" / "tracks" / "reInvent2019_track.npy"
EPISODES_PER_ITERATION = 20
DT = STEP_S


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def timed(fn, repeat: int = 1):
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def drive(track, episodes: int, rng) -> dict[str, np.ndarray]:
    """Simtrace columns of `episodes` episodes wandering along `track`: speed 1-3 m/s, a lateral random walk
    that ends the episode when it leaves the road, a lap when it gets round."""
    steps = rng.integers(20, 300, episodes)
    n = int(steps.sum())
    ep = np.repeat(np.arange(episodes), steps)
    first = np.concatenate([[0], np.cumsum(steps)[:-1]])
    k = np.arange(n) - np.repeat(first, steps)  # 0 on the prepare row
    speed = rng.choice([1.0, 2.0, 3.0], n)
    speed[k == 0] = 0.0
    ds = np.where(k <= 1, 0.0, speed * DT)
    travelled = np.cumsum(ds) - np.repeat(np.cumsum(ds)[first], steps)
    s0 = np.repeat(rng.uniform(0, track.length, episodes), steps)
    s = s0 + travelled
    head = track.heading_at(s)
    lat = np.cumsum(rng.normal(0, 0.01, n))
    lat -= np.repeat(lat[first], steps)
    xy = track.point_at(s) + lat[:, None] * np.stack([-np.sin(head), np.cos(head)], 1)
    last = np.append(ep[1:] != ep[:-1], True)
    progress = np.minimum(100.0, 100 * (travelled + 0.14) / track.length)
    lap = last & (progress >= 100)
    status = np.where(k == 0, "prepare", np.where(last, np.where(lap, "lap_complete", "off_track"), "in_progress"))
    steer = rng.choice([-30.0, -15.0, 0.0, 15.0, 30.0], n)
    return {
        "episode": ep, "steps": k + 1, "X": xy[:, 0], "Y": xy[:, 1],
        "yaw": np.degrees(head) + rng.normal(0, 5, n), "steer": steer, "throttle": speed,
        "action": ((steer + 30) // 15 * 3 + speed - 1).astype(np.int64), "reward": rng.uniform(0, 1, n),
        "done": last, "all_wheels_on_track": ~(last & ~lap), "progress": progress,
        "closest_waypoint": np.zeros(n, np.int64), "track_len": np.full(n, round(track.length, 2)),
        "tstamp": np.round(np.repeat(rng.uniform(0, 5000, episodes), steps) + (k + 1) * DT, 3),
        "episode_status": status, "pause_duration": np.zeros(n), "obstacle_crash_counter": np.zeros(n, np.int64),
        "wall_clock": np.full(n, 1.7e9),
    }


def write_log(folder: Path, track, rows: int, seed: int = 0) -> int:
    rng = np.random.default_rng(seed)
    written, it = 0, 0
    while written < rows:
        cols = drive(track, EPISODES_PER_ITERATION, rng)
        cols["episode"] = cols["episode"] + it * EPISODES_PER_ITERATION
        with SimtraceWriter(training_simtrace_path(folder, it)) as w:
            w.write(cols)
        written += len(cols["steps"])
        it += 1
    return written


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--track", default=str(DEFAULT_TRACK))
    ap.add_argument("--reward", default=str(EXAMPLE_REWARD), help="default: racerlab's example reward function")
    args = ap.parse_args()
    track = tracks.load(args.track)
    tmp = Path(tempfile.mkdtemp(prefix="racerlab-rescore-"))
    try:
        dt, rows = timed(lambda: write_log(tmp / "model", track, args.rows))
        df = load(tmp / "model", cache=False)
        emit(bench="write_and_load_log", rows=len(df), episodes=int(df["unique_episode"].nunique()),
             seconds=round(dt, 2))
        rescore(df.head(2000), args.reward, track)  # compile the geometry kernel outside the timings
        fn = load_reward_function(args.reward)

        dt, pc = timed(lambda: log_params(df, track))
        emit(bench="rebuild_params", rows=len(df), seconds=round(dt, 3))
        dt, res = timed(lambda: score(fn, pc))
        emit(bench="reward_calls", rows=len(df), seconds=round(dt, 3), us_per_row=round(1e6 * dt / len(df), 2),
             reward=Path(args.reward).name)
        dt, res = timed(lambda: rescore(df, args.reward, track))
        emit(bench="rescore_total", rows=len(df), seconds=round(dt, 3), budget_s=20.0, failed=res.failed,
             deepracer_utils_s_estimate=round(36.0 * len(df) / 100_000), speedup=round(36.0 * len(df) / 1e5 / dt, 1))
        dt, cmp = timed(lambda: compare(df, res.new_reward))
        emit(bench="compare_per_episode", episodes=len(cmp), seconds=round(dt, 3))

        dt, kin = timed(lambda: step_kinematics(df), repeat=3)
        emit(bench="step_kinematics", rows=len(df), seconds=round(dt, 3))
        dt, eps = timed(lambda: episode_summary(df, kin), repeat=3)
        emit(bench="episode_summary", rows=len(df), episodes=len(eps), seconds=round(dt, 3),
             deepracer_utils_simulation_agg_s="2.2 for 12 000 episodes (reference)")
        dt, its = timed(lambda: iteration_summary(eps), repeat=3)
        emit(bench="iteration_summary", iterations=len(its), seconds=round(dt, 3))
        x, y, r = df["x"].to_numpy(), df["y"].to_numpy(), df["reward"].to_numpy()
        for stat in ("mean", "median", "count"):
            dt, _ = timed(lambda stat=stat: cell_statistic(x, y, r, stat, 0.05), repeat=3)
            emit(bench=f"heatmap_cells_{stat}", rows=len(df), cell_m=0.05, seconds=round(dt, 3),
                 deepracer_utils_plot_track_s_estimate=round(30.0 * len(df) / 1e6))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
