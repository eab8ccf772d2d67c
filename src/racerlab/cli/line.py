"""`racerlab line TRACK`: the racing line, its speed profile and the theoretical best lap, as files a
racer uses in a reward function and an action space."""

from __future__ import annotations

import math
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("line", help="racing line, speed profile and theoretical best lap of a track",
                       description="Solve the racing line of TRACK (minimum curvature or shortest path, keeping "
                                   "the whole car MARGIN inside the borders) and the fastest speed the "
                                   "simulator's car can drive on it; print its lap time beside the theoretical "
                                   "limit (the fastest lap the simulator's off-track rule allows: a wheel centre "
                                   "on the road) and write a picture, "
                                   "the line as .npy and .csv, a Python list [[x, y, speed], ...] to paste "
                                   "into a reward function and a discrete action space (model_metadata.json) "
                                   "fitted to the line.")
    p.add_argument("track", metavar="TRACK", help="a track name (see `racerlab tracks list`) or a .npy file")
    p.add_argument("--margin", type=float, default=None, metavar="M",
                   help="metres kept between the car's wheels and each border (default 0.1; negative lets them hang "
                        "over it, down to what the off-track rule allows)")
    p.add_argument("--method", default="mincurv",  # checked against line.METHODS in run_line (its one home)
                   help="mincurv: minimum curvature (the fast line, default); shortest: the shortest path")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="folder for the files (default ./<track>_<method>_line, <track>_reversed_... with --reverse)")
    p.add_argument("--reverse", action="store_true", help="the track driven the other way")
    p.add_argument("--simulator", choices=("droa", "console"), default="droa",
                   help="whose car: droa (DeepRacer on AWS / DRfC >= 6, default) or console (the AWS console / DRfC "
                        "<= 5)")
    p.add_argument("--version", default="5", metavar="V",
                   help="the model_metadata version the car is for (3-4: effort control, >= 5: velocity; default 5)")
    p.add_argument("--actions", type=int, default=None, metavar="N",
                   help="number of discrete actions in model_metadata.json (default 15, at least 3)")
    p.set_defaults(func=run_line)


def run_line(args) -> int:
    from racerlab.errors import RacerlabError
    from racerlab.line import DEFAULT_MARGIN_M, METHODS, min_margin, racing_line, theoretical_limit
    from racerlab.line.export import DEFAULT_ACTIONS, write_all
    from racerlab.spec import car_params
    from racerlab.track import load

    margin = DEFAULT_MARGIN_M if args.margin is None else args.margin
    n_actions = DEFAULT_ACTIONS if args.actions is None else args.actions
    version = _version(args.version)
    car = car_params(args.simulator, version)
    if not math.isfinite(margin):
        raise RacerlabError(f"--margin {margin}: not a number of metres; give e.g. --margin 0.1")
    if margin < min_margin(car):
        raise RacerlabError(f"--margin must be >= {min_margin(car):.3f} m (negative: the wheels hang over the border, "
                            f"at most as far as the simulator's off-track rule allows), got {margin}")
    if args.method not in METHODS:
        raise RacerlabError(f"--method {args.method!r} is not a line method; use one of {', '.join(METHODS)}")
    if n_actions < 3:
        raise RacerlabError(f"--actions must be at least 3, got {n_actions}")
    track = load(args.track, reverse=args.reverse)
    line = racing_line(track, margin=margin, method=args.method, car=car)
    limit = theoretical_limit(track, car=car)
    out = args.out or Path(f"{line.track_name}_{args.method}_line")
    paths = write_all(line, track, out, n_actions, version)
    s = line.summary()
    state = "" if line.converged else " (not fully converged: the line may be a little off the optimum)"
    print(f"{line.track_name}: {args.method} line, margin {margin} m, "
          f"{s['length_m']} m in {s['points']} points{state}")
    print(f"line:  lap {line.lap_time:.3f} s (standing start, as the simulator times it), "
          f"flying lap {line.flying_lap_time:.3f} s, speed {s['min_speed_mps']}-{s['max_speed_mps']} m/s, "
          f"solved in {line.solve_s:.2f} s: the line the files hold, the whole car {margin} m inside; car: {car.name}")
    print(f"limit: lap {limit.lap_time:.3f} s, flying lap {limit.flying_lap_time:.3f} s ({limit.method}): the "
          f"theoretical best lap under the simulator's off-track rule (a car is off track only when no wheel "
          f"centre is on the road: its base point may be {-limit.clearance_m:.3f} m outside a border)")
    print(f"wrote into {Path(out).resolve()}:")
    for kind, path in paths.items():
        print(f"  {kind:15s} {path.resolve()}")
    return 0


def _version(text: str) -> float:
    from racerlab.errors import RacerlabError

    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and 1 <= v <= 100):
        raise RacerlabError(f"--version {text}: not a model_metadata version; give e.g. --version 5 (velocity control) "
                            "or --version 4 (effort control)")
    return v
