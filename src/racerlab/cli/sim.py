"""`racerlab sim view`: a picture of what the car's sensors see at several points of a lap."""

from __future__ import annotations

from pathlib import Path

from racerlab.cli.evaluate import _race_flags, race_overrides


def register(sub) -> None:
    p = sub.add_parser("sim", help="look at the simulator's sensors",
                       description="Tools around the simulator. `view` draws the track with cars at several points "
                                   "of a lap and, beside each, its camera frame and its lidar scan.")
    ssub = p.add_subparsers(dest="sim_command", metavar="ACTION", required=True)
    v = ssub.add_parser("view", help="a PNG of the track with what each car's camera and lidar see",
                        description="Place cars on the centre line, evenly spread over the lap, and draw the track "
                                    "from above with each car's 160×120 greyscale camera frame (as the model sees "
                                    "it) and its 64-ray lidar scan.")
    v.add_argument("track", metavar="TRACK", help="track name or file")
    v.add_argument("--out", type=Path, metavar="FILE.png", help="default: sim-view-<track>.png here")
    v.add_argument("--cars", type=int, default=4, metavar="N", help="cars around the lap (default 4, at most 8)")
    v.add_argument("--dr", action="store_true", help="domain randomization: each car gets a random look")
    v.add_argument("--walls", action="store_true",
                   help="the lidar sees the track borders as walls (AWS tracks have none: every ray reads 1 m)")
    v.add_argument("--seed", type=int, default=0)
    _race_flags(v)  # e.g. --race-type object_avoidance --number-of-obstacles 6: the boxes are drawn and seen
    v.set_defaults(func=run_view)


def run_view(args) -> int:
    from racerlab import track as tracks
    from racerlab.errors import RacerlabError
    from racerlab.sim.sensors.view import sensor_view

    if not 1 <= args.cars <= 8:
        raise RacerlabError(f"--cars must be between 1 and 8, got {args.cars}")
    t = tracks.load(args.track)
    out = args.out or Path(f"sim-view-{t.name}.png")
    race = race_overrides(args)
    if race and "type" not in race:  # object keys alone say which race
        bots = any(k.endswith("bot_cars") or k.startswith("bot_") for k in race)
        race["type"] = "head_to_bot" if bots else "object_avoidance"
    fig = sensor_view(t, args.cars, randomize=args.dr, walls=args.walls, seed=args.seed, race=race or None)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
    return 0
