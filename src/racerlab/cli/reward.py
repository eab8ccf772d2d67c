"""`racerlab reward check|map|rescore`: test a reward function over a whole track, picture it on the track
surface, and re-score logged steps with it."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def register(sub) -> None:
    p = sub.add_parser("reward", help="check, map or re-score a reward function",
                       description="Tools for a reward_function.py: `check` calls it over states sampled over a "
                                   "whole track, `map` draws it over the track surface, `rescore` evaluates it on "
                                   "logged steps and compares it with the logged reward.")
    rsub = p.add_subparsers(dest="reward_command", metavar="ACTION", required=True)

    c = rsub.add_parser("check", help="call the reward over sampled states; report errors and statistics",
                        description="Import the reward function and call it over states sampled over the whole "
                                    "track (positions across and beyond the width, headings, speeds, steering, "
                                    "off-track, reversed and lap-complete cases). Reports exceptions with the "
                                    "params that caused them, values that are not finite numbers within ±1e5, and "
                                    "how the reward varies with distance from centre, heading error, speed and "
                                    "steering. Exit status 1 when a problem was found.")
    c.add_argument("reward", type=Path, metavar="reward_function.py")
    _track_flag(c)
    c.add_argument("--samples", type=int, default=100, metavar="N",
                   help="sampled states per centre segment (default 100)")
    c.add_argument("--seed", type=int, default=0)
    c.set_defaults(func=run_check)

    m = rsub.add_parser("map", help="a picture of the reward over the track surface",
                        description="Evaluate the reward on a grid covering the track (every --cell metres along "
                                    "it, --across positions between the borders and a margin beyond them) for one "
                                    "speed, heading rule and steering angle, and save it as a PNG with the line "
                                    "of highest reward across the width.")
    m.add_argument("reward", type=Path, metavar="reward_function.py")
    _track_flag(m)
    m.add_argument("--speed", type=float, default=2.0, metavar="V", help="speed param, m/s (default 2)")
    m.add_argument("--heading", default="along",
                   help="along (default), against, an offset in degrees from the track direction (+ = left, "
                        "e.g. 15), or aim:K (pointing at the K-th centre waypoint ahead)")
    m.add_argument("--steering", type=float, default=0.0, metavar="DEG", help="steering_angle param (default 0)")
    m.add_argument("--cell", type=float, default=0.05, metavar="M", help="grid step along the track (default 0.05 m)")
    m.add_argument("--across", type=int, default=21, metavar="N", help="grid cells between the borders (default 21)")
    m.add_argument("--out", type=Path, metavar="FILE.png",
                   help="default: <reward file stem>-map.png beside the reward file (in its model folder)")
    m.set_defaults(func=run_map)

    r = rsub.add_parser("rescore", help="evaluate a new reward on logged steps and compare it with the old",
                        description="Re-evaluate a reward function on every logged step, with every AWS param "
                                    "rebuilt from the log and the track (degrees; track_width, is_left_of_center, "
                                    "closest_waypoints from the track; off-track flags), then compare the logged "
                                    "and the new reward per episode against lap time: a table and a scatter PNG.")
    r.add_argument("log", type=Path, metavar="LOG", help="model folder, log folder or log file")
    r.add_argument("--reward", type=Path, required=True, metavar="new.py", help="the reward function to evaluate")
    _track_flag(r)
    r.add_argument("--kind", choices=["auto", "training", "evaluation", "leaderboard"], default="auto")
    r.add_argument("--direction", choices=["auto", "forward", "reverse"], default="auto",
                   help="driving direction for is_reversed and the waypoints (default: per episode, from headings)")
    r.add_argument("--out", type=Path, metavar="FILE.png",
                   help="scatter plot (default: rescore-<reward stem>.png in the model or log folder, or beside "
                        "the log file)")
    r.add_argument("--csv", type=Path, metavar="FILE.csv", help="also write the per-episode comparison")
    r.set_defaults(func=run_rescore)


def _track_flag(p) -> None:
    p.add_argument("--track", help="track name or file (default: the training track of the model folder the reward "
                                   "file is in)")


def _track_for_reward(reward: Path, name: str | None):
    """The --track, else the track of the model folder holding the reward file, else the default track."""
    from racerlab import track as tracks
    from racerlab.errors import RacerlabError
    from racerlab.model import resolve_track

    if name:
        return tracks.load(name)
    try:
        t = resolve_track(reward.resolve().parent, default=False)
    except RacerlabError:  # a broken training.toml or a track that is gone: the default track will do
        t = None
    return t if t is not None else tracks.load(tracks.DEFAULT_TRACK)


def run_check(args) -> int:
    from racerlab.analysis.reward_tools import check_reward

    track = _track_for_reward(args.reward, args.track)
    report = check_reward(args.reward, track, per_segment=args.samples, seed=args.seed)
    print(report.format())
    return 0 if report.ok else 1


def run_map(args) -> int:
    from racerlab.analysis.plots import reward_map_figure, save_png
    from racerlab.analysis.reward_tools import parse_heading, reward_map
    from racerlab.errors import RacerlabError

    try:
        parse_heading(args.heading)
    except ValueError as exc:
        raise RacerlabError(str(exc)) from None
    track = _track_for_reward(args.reward, args.track)
    rm = reward_map(args.reward, track, speed=args.speed, heading=args.heading, steering=args.steering,
                    ds=args.cell, across=args.across)
    out = save_png(reward_map_figure(rm), args.out or args.reward.with_name(f"{args.reward.stem}-map.png"))
    for p in rm.problems:
        print("warning: " + p.describe(), file=sys.stderr)
    print(f"picture: {out.resolve()}")
    return 0


def run_rescore(args) -> int:
    from racerlab.cli import require_path

    require_path(args.log)
    require_path(args.reward, "reward file")
    from racerlab.analysis.load import load
    from racerlab.analysis.plots import reward_vs_lap_time, save_png
    from racerlab.analysis.report import log_track
    from racerlab.analysis.rescore import compare, correlations, rescore
    from racerlab.errors import RacerlabError

    df = load(args.log, args.kind)
    if len(df) == 0:
        raise RacerlabError(f"{args.log}: the logs hold no steps to re-score")
    track, note = log_track(args.log, df, args.track)
    if track is None:
        raise RacerlabError(f"{args.log}: no track to rebuild the params on: {note}")
    reverse = {"auto": None, "forward": False, "reverse": True}[args.direction]
    res = rescore(df, args.reward, track, reverse=reverse)
    print(f"re-scored {len(df):,} steps of {df['unique_episode'].nunique():,} episodes on {track.name} in "
          f"{res.seconds:.2f} s (reward calls {res.reward_seconds:.2f} s); "
          f"{res.reversed_episodes} episodes driven reversed")
    if not res.ok:
        print(f"PROBLEMS: the new reward failed on {res.failed:,} steps (their episodes get no new total):")
        for p in res.problems:
            print("  - " + p.describe().replace("\n", "\n    "))
    cmp = compare(df, res.new_reward)
    _print_comparison(cmp, correlations(cmp))
    folder = args.log if args.log.is_dir() else args.log.parent
    out = save_png(reward_vs_lap_time(cmp), args.out or folder / f"rescore-{args.reward.stem}.png")
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        cmp.to_csv(args.csv)
        print(args.csv)
    print(out)
    return 0 if res.failed < len(df) else 1


def _print_comparison(cmp, corr) -> None:
    import pandas as pd

    laps = cmp[cmp["complete"]].sort_values("lap_time")
    with pd.option_context("display.width", 160, "display.max_columns", 20):
        if len(laps):
            t = laps[["iteration", "lap_time", "reward", "new_reward"]].copy()
            t["iteration"] += 1  # as the training console and the checkpoint names count them
            t["reward_rank"] = laps["reward"].rank(ascending=False).astype(int)
            t["new_rank"] = laps["new_reward"].rank(ascending=False, na_option="bottom").astype(int)
            print(f"\ncomplete laps, fastest first (rank 1 = most reward; {len(laps)} laps):")
            print(t.head(15).to_string(float_format=lambda v: f"{v:.3f}"))
        else:
            print("\nno complete laps in this log: compare with progress below")
        print("\nper episode, all outcomes (totals):")
        print(cmp[["reward", "new_reward", "progress", "time"]].describe().loc[["mean", "std", "min", "max"]]
              .to_string(float_format=lambda v: f"{v:.3f}"))
        print("\nSpearman rank correlation (a reward that pays for speed: strongly negative vs lap time):")
        print(corr.to_string(float_format=lambda v: "n/a" if np.isnan(v) else f"{v:+.2f}"))
