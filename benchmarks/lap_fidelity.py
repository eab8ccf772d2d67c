"""Lap fidelity: every real evaluation lap of the shared logs, driven again in racerlab's car.

For each completed evaluation lap a driver in racerlab's car of the same simulator and model version follows the
logged path (pure pursuit on the logged base points) at the logged speeds (each step it commands the logged
action speed of the logged row nearest its front point), from the lap's first logged pose and speed, on exact
1/15 s steps. One JSON line per lap: whether it stayed on track, its lap time (steps × 1/15 s, as racerlab and
the simulator's step count time a lap) against the logged one (the lap's rows × 1/15 s; the tstamp span beside
it), and the mean distance between the driven and the logged paths.

    python benchmarks/lap_fidelity.py                  # every lap, the built-in cars
    python benchmarks/lap_fidelity.py --plot lap.png   # also the first console 2025 lap overlaid

Target (issue 34): on track, lap time within 3 % of the logged one.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import numpy as np

from car_fidelity import _paths  # the benchmark beside this one: the shared logs, tarballs unpacked
from racerlab.analysis import load
from racerlab.sim import Simulator
from racerlab.sim import _kernels as K
from racerlab.sim.pursuit import PurePursuit
from racerlab.spec import MODEL_POINT_AHEAD_M, STEP_S, car_params
from racerlab.track import load_file

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
# name: (evaluation log, track file stem, simulator, model version)
LAPS = {
    "drfc2022-v4": (["real_logs/sample-drfc-1-logs/evaluation-20220709200242",
                     "real_logs/sample-drfc-1-logs/evaluation-20220709200509",
                     "real_logs/sample-drfc-1-logs/evaluation-20220709200711"], "reinvent_base", "console", "4"),
    "console2022": (["real_logs/sample-console-logs/sim-trace/evaluation"], "reinvent_base", "console", "4"),
    "console2025-fast-4a": (["simtraces/console2025oct-v5-highspeed/reinvencementModel-clone1/Evaluation"],
                            "reinvent_base", "console", "5"),
    "droa2026-evaluation": (["simtraces/droa2026-v6-Spain_track-evaluation"], "Spain_track", "droa", "5"),
}


LOOKAHEAD_M = 0.15  # short: the driver follows the logged path's weaving instead of cutting it


class LoggedDriver:
    """Pure pursuit on a logged lap's base points, commanding the logged speed of the row nearest the front
    point."""

    def __init__(self, front: np.ndarray, base: np.ndarray, speed: np.ndarray, lookahead_m: float):
        self.front, self.speed = front, speed
        self.pursuit = PurePursuit(base, speed, closed=True, lookahead_m=lookahead_m, lookahead_gain_s=0.05)
        self.hint = 0

    def __call__(self, sim):
        steer, _ = self.pursuit(sim)
        x, y, yaw = sim.car[0, K.CX], sim.car[0, K.CY], sim.car[0, K.CYAW]
        fx, fy = x + MODEL_POINT_AHEAD_M * math.cos(yaw), y + MODEL_POINT_AHEAD_M * math.sin(yaw)
        win = np.arange(self.hint, min(self.hint + 12, len(self.front)))  # rows ahead of the last match
        k = int(win[np.argmin(np.hypot(self.front[win, 0] - fx, self.front[win, 1] - fy))])
        self.hint = k
        return steer, np.array([self.speed[k]])


def laps_of(df):
    """(rows of each completed lap in driving order, whether it was driven without resets). A continuous
    evaluation's laps are its episodes; one is complete when its progress reaches 100 %."""
    out = []
    for _, e in df.groupby("unique_episode", sort=True):
        e = e.sort_values("steps")
        status = e["episode_status"].astype(str).to_numpy()
        done = (status == "lap_complete") | (e["progress"].to_numpy(float) >= 100.0)
        if not done.any():
            continue
        end = int(np.flatnonzero(done)[0])
        lap = e.iloc[:end + 1]
        clean = not np.isin(status[:end + 1], ["off_track", "pause", "crashed"]).any()
        out.append((lap, clean))
    return out


def drive(lap, track, car, lookahead_m: float = LOOKAHEAD_M):
    """Drive one logged lap in `car`: (status, steps, driven front points (T, 2))."""
    front = lap[["x", "y"]].to_numpy(float)
    yaw = np.radians(lap["yaw"].to_numpy(float))
    base = front - MODEL_POINT_AHEAD_M * np.column_stack([np.cos(yaw), np.sin(yaw)])
    speed = lap["speed"].to_numpy(float)
    first_v = float(np.hypot(*(front[2] - front[1])) / STEP_S) if lap["steps"].iloc[0] > 1 else 0.0
    s = track.project(front[5:15]).s
    reverse = bool(np.median(np.diff(s)) < 0)
    sim = Simulator(track, 1, car)
    sim.reset()
    sim.set_pose(0, float(base[0, 0]), float(base[0, 1]), float(yaw[0]), speed=first_v, reverse=reverse)
    for _ in range(K.QUEUE):  # the car has been acting on the lap's first command
        K.push(0, sim.car, math.radians(float(lap["steering_angle"].iloc[0])), float(speed[0]))
    driver = LoggedDriver(front, base, speed, lookahead_m)
    path = []
    for _ in range(3 * len(lap)):
        steer, v = driver(sim)
        codes = sim.step(steer, v)
        x, y, yw = sim.car[0, K.CX], sim.car[0, K.CY], sim.car[0, K.CYAW]
        path.append([x + MODEL_POINT_AHEAD_M * math.cos(yw), y + MODEL_POINT_AHEAD_M * math.sin(yw)])
        if sim.terminated_mask(codes)[0] or sim.truncated[0]:
            break
    return K.STATUS_NAMES[int(sim.status[0])], int(sim.steps[0]), np.array(path)


def _path_gap(driven: np.ndarray, logged: np.ndarray) -> float:
    """Mean distance (m) from each driven front point to the nearest logged one."""
    d = np.hypot(driven[:, None, 0] - logged[None, :, 0], driven[:, None, 1] - logged[None, :, 1])
    return float(d.min(axis=1).mean())


def plot_lap(track, lap, driven, title: str, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 6))
    for border in (track.left, track.right):
        ax.plot(border[:, 0], border[:, 1], color="0.6", lw=1)
    ax.plot(lap["x"], lap["y"], "k-", lw=1.5, label="logged (real simulator)")
    ax.plot(driven[:, 0], driven[:, 1], "-", color="tab:red", lw=1.2, label="racerlab's car, same driver")
    ax.set_aspect("equal")
    ax.legend(loc="best")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", nargs="*", default=list(LAPS))
    ap.add_argument("--plot", default=None, help="write the first lap of the first set overlaid to this PNG")
    ap.add_argument("--lookahead", type=float, default=LOOKAHEAD_M, help="the pursuit's lookahead at 0 m/s (m)")
    args = ap.parse_args()
    plotted = False
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.sets:
            rel, stem, sim_name, version = LAPS[name]
            track = load_file(SHARED / "tracks" / f"{stem}.npy")
            car = car_params(sim_name, version, step_jitter=False)
            for n, p in enumerate(_paths(rel, Path(tmp))):
                for k, (lap, clean) in enumerate(laps_of(load(p))):
                    status, steps, driven = drive(lap, track, car, args.lookahead)
                    logged_s = len(lap) * STEP_S
                    ours = steps * STEP_S if status == "lap_complete" else math.nan
                    print(json.dumps({"set": name, "log": n, "lap": k, "car": car.name, "clean": clean,
                                      "status": status, "on_track": status == "lap_complete",
                                      "logged_s": round(logged_s, 3),
                                      "logged_tstamp_s": round(float(np.ptp(lap["tstamp"])), 3),
                                      "racerlab_s": round(ours, 3), "ratio": round(ours / logged_s, 4),
                                      "path_gap_m": round(_path_gap(driven, lap[["x", "y"]].to_numpy(float)), 3)}),
                          flush=True)
                    if args.plot and not plotted:
                        plot_lap(track, lap, driven, f"{name}, lap {k}: logged {logged_s:.2f} s, racerlab "
                                 f"{ours:.2f} s ({car.name})", args.plot)
                        plotted = True


if __name__ == "__main__":
    main()
