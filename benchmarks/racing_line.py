"""Racing line: solve time on a 200-waypoint track, the reInvent2019 calibration anchor, and predicted vs
driven lap times (pure pursuit on the line at the profile's speed in the simulator). One JSON line per
measurement.

Budget (DESIGN.md): racing line for a 200-waypoint track <= 1 s (the k1999 notebook: ~11 s for 71 points,
reference/analysis_and_racing_line_tools.md §4). Anchor: the theoretical best lap of reInvent2019_track in
6.5-7.2 s (best human-trained lap in the AWS simulator: 7.198 s).

    python benchmarks/racing_line.py [--repeat 3] [--margin 0.1]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from racerlab.errors import TrackError
from racerlab.line import racing_line
from racerlab.sim import Simulator
from racerlab.sim.pursuit import PurePursuit, drive_lap
from racerlab.track import load, load_file

REPO = Path(__file__).resolve().parents[1]
AWS = REPO.parent / "shared" / "tracks"
SOLVE_TRACKS = ("thunder_hill_pro_ccw", "reInvent2019_track", "penbay_pro")  # 200 waypoints, the anchor, longest
DRIVE_TRACKS = ("reinvent_base", "reInvent2019_track", "2022_reinvent_champ")
BUNDLED = ("lab_oval", "lab_technical", "lab_grand_prix")
RECORD_S = 7.198


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def solve_times(repeat: int, margin: float) -> None:
    for name in SOLVE_TRACKS:
        track = load_file(AWS / f"{name}.npy")
        for method in ("mincurv", "shortest"):
            best, line = float("inf"), None
            for _ in range(repeat):
                t0 = time.perf_counter()
                line = racing_line(track, margin=margin, method=method)
                best = min(best, time.perf_counter() - t0)
            emit(measure="solve_time", track=name, waypoints=track.num_waypoints, points=len(line.xy), method=method,
                 seconds=round(best, 3), budget_s=1.0, iterations=line.iterations, converged=line.converged)


def anchor() -> None:
    track = load_file(AWS / "reInvent2019_track.npy")
    for margin in (0.1, 0.05, 0.0):
        line = racing_line(track, margin=margin)
        emit(measure="anchor", track="reInvent2019_track", margin_m=margin, lap_time_s=round(line.lap_time, 3),
             flying_lap_time_s=round(line.flying_lap_time, 3), window_s=[6.5, 7.2], record_s=RECORD_S,
             inside=bool(6.5 <= line.lap_time <= 7.2))


def drive(track, name: str, margin: float) -> None:
    line = racing_line(track, margin=margin)
    sim = Simulator(track, 1)
    status, steps, lap_s, _ = drive_lap(sim, PurePursuit(line.xy, line.speed, closed=True, car=sim.car_params))
    emit(measure="lap", track=name, margin_m=margin, length_m=round(line.length, 2), status=status,
         predicted_s=round(line.lap_time, 3), driven_s=round(lap_s, 3),
         diff_pct=round(100.0 * (lap_s / line.lap_time - 1.0), 2), flying_predicted_s=round(line.flying_lap_time, 3))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="solves per timing, best kept (default 3)")
    ap.add_argument("--margin", type=float, default=0.1, help="line margin in m (default 0.1)")
    args = ap.parse_args()
    solve_times(args.repeat, args.margin)
    anchor()
    for name in DRIVE_TRACKS:
        drive(load_file(AWS / f"{name}.npy"), name, args.margin)
    for name in BUNDLED:
        try:
            track = load(name)
        except TrackError:
            emit(measure="lap", track=name, status="track not found")
            continue
        drive(track, name, args.margin)


if __name__ == "__main__":
    main()
