"""`racerlab calibrate LOGS...`: fit racerlab's car to a real simulator's logs and write the `[car]` table."""

from __future__ import annotations

import math
import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="fit the car to real simulator logs and write a [car] table",
                       description="Fit racerlab's car (delay, hinge lag, yaw gain and slide, traction, ground "
                                   "speed) to the simtraces of a real simulator: any simtrace folder, console/DRoA "
                                   "export or robomaker log. Every third episode is held out: the report gives "
                                   "the median front-point error after 1, 3, 8 and 15 steps beside the "
                                   "constant-velocity guess, the constants with their spread, and a picture. "
                                   "The [car] table it writes goes into a model's training.toml.")
    p.add_argument("logs", nargs="+", type=Path, metavar="LOGS", help="log folders, exports or files")
    p.add_argument("--simulator", choices=("droa", "console"), default="droa",
                   help="the simulator the logs come from (default droa)")
    p.add_argument("--version", default="5", metavar="V",
                   help="the model_metadata version of the logged model (3-4: effort control; default 5)")
    p.add_argument("--out", type=Path, default=Path("car.toml"), metavar="FILE",
                   help="the .toml file for the [car] table (default car.toml): a new file, an earlier car.toml or a "
                        "model's training.toml, whose other tables and keys are kept; the picture goes beside it "
                        "as .png")
    p.add_argument("--resamples", type=int, default=3, metavar="N",
                   help="fits on resampled episodes for the constants' spread (default 3; 0: none)")
    p.set_defaults(func=run_calibrate)


def interval_line(fit) -> str:
    """How far the held-out figure after 1 s would move with other episodes (`Fit.held_out_interval`)."""
    from racerlab.calibrate.fit import MIN_EPISODES

    lo, hi = fit.held_out_interval
    n = fit.held_out_episodes
    if math.isfinite(lo):
        return (f"the fitted car's median after {list(fit.held_out)[-1]} steps lies within {lo:.3f}-{hi:.3f} m in 90 % "
                f"of resamples of the {n} held-out episodes")
    return (f"only {n} episode{'' if n == 1 else 's'} held out: too few to say how far the figures would move with "
            f"other episodes (logs of {3 * MIN_EPISODES} or more episodes say it)")


def check_trainable(text: str) -> None:
    """The `[car]` table as training reads it (`model`'s own check): what calibrate writes, train takes."""
    import tomllib

    from racerlab.model.config import CarSettings

    CarSettings.from_mapping(tomllib.loads(text)["car"], where="the [car] table racerlab calibrate made")


def run_calibrate(args) -> int:
    from racerlab.calibrate import calibrate, car_toml
    from racerlab.calibrate.out import check_out, table_text
    from racerlab.calibrate.plot import plot_fit
    from racerlab.calibrate.run import check_distinct, check_log_path, check_resamples, check_version, on_bounds
    from racerlab.logs import atomic_write_text

    out = check_out(args.out)  # all of it before the fit, which takes minutes
    check_resamples(args.resamples)
    check_version(args.version)
    for p in args.logs:
        check_log_path(p)
    check_distinct(args.logs)
    names = ", ".join(str(p) for p in args.logs)
    fit = calibrate(args.logs, args.simulator, args.version, resamples=args.resamples,
                    say=lambda text: print(text, file=sys.stderr, flush=True))
    print(f"{fit.fit_stretches} stretches fitted, {fit.held_out_stretches} held out")
    print("median front-point error on held-out episodes (m):")
    print("  after steps      " + "".join(f"{h:>8d}" for h in fit.held_out))
    print("  fitted car       " + "".join(f"{v:8.3f}" for v in fit.held_out.values()))
    print("  constant velocity" + "".join(f"{v:8.3f}" for v in fit.constant_velocity.values()))
    print("  learned floor    " + "".join(f"{v:8.3f}" for v in fit.floor.values())
          + "  (the fitted car corrected by a regression learned on the fit episodes)")
    print(interval_line(fit))
    text = car_toml(fit, names)
    check_trainable(text)
    print(text, end="")
    for warning in on_bounds(fit):
        print(f"warning: {warning}", file=sys.stderr)
    merged = out.exists()
    atomic_write_text(out, table_text(out, text))
    png = plot_fit(fit, out.with_suffix(".png"))
    print(f"{'merged the [car] table into' if merged else 'wrote'} {args.out}; the picture: {png}")
    return 0
