"""`racerlab init | train | clone`: model folders and training."""

from __future__ import annotations

import math
import shlex
import shutil
from pathlib import Path

from racerlab.errors import ConfigError, RacerlabError

DEFAULT_MAX_SPEED = 1.0  # the AWS console's default action space tops out at 1 m/s


def register(sub) -> None:
    from racerlab.logs.metrics import BEST_MODEL_METRICS
    from racerlab.model.init import PRESETS
    from racerlab.reward import TEMPLATES as REWARD_TEMPLATES

    p = sub.add_parser("init", help="create a model folder with AWS-default files",
                       description="Write reward_function.py, model_metadata.json, hyperparameters.json and "
                                   "training.toml into a new model folder.")
    p.add_argument("model", type=Path)
    p.add_argument("--track", help="training track (default: the bundled default track)")
    p.add_argument("--sensor", choices=["features", "camera", "stereo", "lidar"], default="features")
    p.add_argument("--action-space", choices=["discrete", "continuous"], default="discrete")
    p.add_argument("--algorithm", choices=["clipped_ppo", "sac"], default="clipped_ppo")
    p.add_argument("--max-speed", type=float, default=DEFAULT_MAX_SPEED,
                   help=f"top action speed in m/s (default {DEFAULT_MAX_SPEED:g}, the AWS console's; the quickstart "
                        f"uses {QUICKSTART_MAX_SPEED:g})")
    p.add_argument("--cars", type=int, help="cars simulated in parallel")
    p.add_argument("--best-model-metric", choices=BEST_MODEL_METRICS,
                   help="what picks the best checkpoint: mean eval progress (AWS default), reward or lap time")
    p.add_argument("--reward", choices=list(REWARD_TEMPLATES), default="example",
                   help="reward template: example (centre, heading and speed), centre_line, progress (progress "
                        "per step), racing_line (the path of the track's limit from `racerlab line`, kept "
                        "--line-margin from the borders, at its speeds)")
    p.add_argument("--line-margin", type=float, default=None,
                   help="racing_line: metres between the wheels and the borders (negative: over them; default "
                        "-0.1, the least the off-track rule allows is about -0.23)")
    p.add_argument("--race", choices=["time_trial", "object_avoidance", "head_to_bot", "head_to_model"],
                   default="time_trial",
                   help="object_avoidance: three boxes in [race], head_to_bot: three bot cars, head_to_model: the "
                        "cars race in pairs (self-play); each with an example reward using objects_* (with --reward "
                        "example)")
    p.add_argument("--preset", choices=list(PRESETS),
                   help="training preset: generalise (8 generated tracks, new ones every 5 iterations; a lidar "
                        "model sees the borders as walls; with --tracks-from the tracks of a folder instead, the "
                        "pace reward and, for a camera model, a longer teacher and randomised training)")
    p.add_argument("--tracks-from", type=Path, metavar="DIR",
                   help="with --preset generalise: train on every track layout of DIR (AWS .npy files, e.g. from "
                        "`racerlab tracks fetch --all`) except --held-out ones, which training.toml's header names")
    p.add_argument("--held-out", type=int, default=20, metavar="N",
                   help="with --tracks-from: layouts kept out of training, for `racerlab evaluate --tracks-from` "
                        "(default 20)")
    p.add_argument("--held-out-seed", type=int, default=0, help="with --tracks-from: which layouts are held out")
    p.add_argument("--no-teacher", action="store_true",
                   help="a camera model learns by PPO alone (default: it first trains a features teacher in its "
                        "folder and learns the teacher's actions, near the limit in minutes on a CPU)")
    p.add_argument("--force", action="store_true", help="overwrite the files of an existing folder")
    p.set_defaults(func=run_init)

    p = sub.add_parser("train", help="train a model folder (resumes when it has checkpoints)")
    p.add_argument("model", type=Path)
    p.add_argument("--minutes", type=float, help="stop after this many minutes")
    p.add_argument("--episodes", type=int, help="stop after this many training episodes")
    p.add_argument("--iterations", type=int, help="stop after this many iterations")
    p.add_argument("--cars", type=int, help="cars simulated in parallel")
    p.add_argument("--track", action="append", help="training track (repeat for several)")
    p.add_argument("--device", help="auto, cpu, cuda or cuda:N")
    p.add_argument("--seed", type=int)
    p.add_argument("--workers", type=int, help="collect with N Ray rollout workers (needs racerlab[cluster])")
    p.add_argument("--ray-address", help="an existing Ray cluster, e.g. 10.0.0.1:6379 (default: a local Ray)")
    p.add_argument("--teacher", type=Path,
                   help="a trained features model whose actions a camera model learns (DAgger), used as it is; "
                        "default: training.toml's [teacher] model")
    p.set_defaults(func=run_train)

    p = sub.add_parser("clone", help="start a new model from another model's checkpoint")
    p.add_argument("src", type=Path)
    p.add_argument("dst", type=Path)
    p.add_argument("--checkpoint", default="best", help="best (default), last or an iteration number")
    p.add_argument("--reward", type=Path, help="a new reward_function.py")
    p.add_argument("--model-metadata", type=Path, help="a new model_metadata.json (same actions count and sensors)")
    p.add_argument("--hyperparameters", type=Path, help="a new hyperparameters.json")
    p.add_argument("--track", help="a new training track")
    p.set_defaults(func=run_clone)


def run_init(args) -> int:
    from racerlab.model import init_model

    check_line_margin(args.reward, args.line_margin, args.track)
    new = not Path(args.model).exists()
    folder = init_model(args.model, track=args.track, sensor=args.sensor, action_space=args.action_space,
                        algorithm=args.algorithm, max_speed=args.max_speed, num_cars=args.cars,
                        best_model_metric=args.best_model_metric, force=args.force, race=args.race,
                        preset=args.preset, teacher=not args.no_teacher, tracks_from=args.tracks_from,
                        held_out=args.held_out, held_out_seed=args.held_out_seed)
    try:
        write_template(folder, args.reward, args.line_margin)
    except RacerlabError as exc:  # the line cannot be drawn: no half-made folder is left to trip the next init
        if new:
            shutil.rmtree(folder.path, ignore_errors=True)
        raise RacerlabError(str(exc).replace("(--margin)", "(--line-margin)")) from None
    reward = "pace" if args.tracks_from is not None and args.reward == "example" else args.reward
    print(f"created {folder.path}: reward_function.py ({reward}), model_metadata.json, hyperparameters.json, "
          "training.toml")
    print(speed_note(args.max_speed))
    if args.sensor == "features":
        print(FEATURES_NOTE)
    taught = folder.config().teacher.model  # a camera model with a features teacher laps within a few minutes
    minutes = 5 if args.sensor == "features" else TAUGHT_MINUTES if taught else CAMERA_MINUTES
    print(f"next: edit the reward function, then `racerlab train {shlex.quote(str(folder.path))} --minutes {minutes}`")
    return 0


def write_template(folder, reward: str, line_margin: float | None = None) -> None:
    """Write reward template `reward` into a new model folder (the example is there already); racing_line gets
    the line of the folder's first track for the car it trains (`reward_line`)."""
    if reward == "example":
        return
    from racerlab.reward import reward_source
    from racerlab.reward.templates import NEEDS_LINE

    line = None
    metadata = folder.metadata()
    if reward in NEEDS_LINE:
        car = folder.config().car.params(metadata.version, training=False)  # the [car] it trains
        line = reward_line(folder.config().track.names[0], car, line_margin)
    folder.write_reward(reward_source(reward, line, metadata.actions.top_speed))


def check_line_margin(reward: str, margin: float | None, track: str | None = None) -> None:
    """`--line-margin` checked before a folder is made: only racing_line takes one, a number of metres from no less
    than the off-track rule allows to no more than the narrowest place of `track` (default: a new model's) leaves
    (the cars share their wheels' geometry, so a new model's default car stands for all)."""
    if margin is None:
        return
    from racerlab.reward.templates import NEEDS_LINE
    from racerlab.spec import car_params

    if reward not in NEEDS_LINE:
        raise ConfigError(f"--line-margin {margin:g}: only --reward {' / '.join(NEEDS_LINE)} follows a line; drop "
                          "--line-margin or add --reward racing_line")
    if not math.isfinite(margin):
        raise ConfigError(f"--line-margin {margin}: not a distance; give metres between the wheels and the borders, "
                          "e.g. 0.1")
    car = car_params()
    _check_margin(margin, car)
    _check_room(margin, track, car)


def _check_room(margin: float, track: str | None, car) -> None:
    """The margin must leave the car room at the track's narrowest place: half the width, less the car's own
    clearance (`line.car_clearance` at a margin of 0)."""
    from racerlab import track as tracks
    from racerlab.line import car_clearance, min_margin
    from racerlab.model.config import TrainingConfig

    name = track or TrainingConfig().track.names[0]
    narrowest = float(tracks.load(name).widths.min())
    most = 0.5 * narrowest - car_clearance(car, 0.0)
    if margin > most:
        raise ConfigError(f"--line-margin {margin:g}: {name} is {narrowest:.2f} m wide at its narrowest, which leaves "
                          f"at most {most:.3f} m between the wheels and each border; choose {min_margin(car):.3f} to "
                          f"{most:.3f} m")


def _check_margin(margin: float, car) -> None:
    from racerlab.line import min_margin

    if not margin >= min_margin(car):
        raise ConfigError(f"--line-margin {margin:g}: the off-track rule allows no less than {min_margin(car):.3f} m "
                          "for this car; choose a larger margin")


def reward_line(track, car, margin: float | None = None):
    """The line the racing_line reward follows: the limit's kind of path (`line.fastest_line`) `margin` m from
    the borders (default `reward.templates.LINE_MARGIN_M`); a margin the car cannot keep is one line naming it."""
    from racerlab.line import fastest_line
    from racerlab.reward.templates import LINE_MARGIN_M

    margin = LINE_MARGIN_M if margin is None else margin
    _check_margin(margin, car)
    return fastest_line(track, margin, car)


# `racerlab quickstart`'s new model: continuous actions up to the simulator's 4 m/s and the racing_line reward, so
# that its best checkpoint comes late in its run (docs/learner.md; with 2 m/s discrete actions and the example
# reward the car sat at its top speed within a minute and the best checkpoint was iteration 13 of 617)
QUICKSTART_MAX_SPEED = 4.0  # `racerlab quickstart --max-speed`'s default
QUICKSTART_ACTIONS = "continuous"
QUICKSTART_REWARD = "racing_line"


def speed_note(max_speed: float) -> str:
    """What the action speeds are and how they differ from the quickstart's."""
    if max_speed == DEFAULT_MAX_SPEED:
        return (f"actions: top speed {max_speed:g} m/s, the AWS console's default; the quickstart's model has "
                f"{QUICKSTART_ACTIONS} actions up to {QUICKSTART_MAX_SPEED:g} m/s and the {QUICKSTART_REWARD} reward "
                f"(init with --action-space {QUICKSTART_ACTIONS} --max-speed {QUICKSTART_MAX_SPEED:g} --reward "
                f"{QUICKSTART_REWARD} for that)")
    return f"actions: top speed {max_speed:g} m/s (--max-speed; the AWS console's default is {DEFAULT_MAX_SPEED:g})"


FEATURES_NOTE = ("note: sensor FEATURES (speed, steering, offsets and the centre line ahead, the fastest to train) "
                 "is racerlab's own: the AWS console and DRfC accept only cameras and LIDAR, so this model trains, "
                 "races and is analysed here only; `racerlab init --sensor camera` makes one you can upload or put on "
                 "the car (`racerlab export --car`)")


def run_train(args) -> int:
    import signal

    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # a shell that starts a job in the background makes it ignore SIGINT, and Python then never raises
        # KeyboardInterrupt; Ctrl-C's meaning (save the last complete iteration, stop) is what `kill -INT`
        # and the console's stop button rely on
        signal.signal(signal.SIGINT, signal.default_int_handler)
    overrides = {"minutes": args.minutes, "episodes": args.episodes, "iterations": args.iterations,
                 "num_cars": args.cars, "device": args.device, "seed": args.seed, "tracks": args.track}
    if args.teacher is not None and args.workers is not None:
        raise RacerlabError(f"--teacher {args.teacher}: a teacher trains on this machine only; drop --workers")
    if args.workers is None and args.ray_address:
        raise RacerlabError(f"--ray-address {args.ray_address}: give --workers N as well to train on the cluster")
    from racerlab.cli import require_models
    from racerlab.model import ModelFolder

    require_models(args.model)
    if args.workers is not None:
        from racerlab.cli.cluster import require_ray
        from racerlab.cluster import train_on_cluster

        require_ray()
        result = train_on_cluster(args.model, args.workers, args.ray_address, **overrides)
    else:
        from racerlab.train import train

        teacher = args.teacher is not None or bool(ModelFolder(args.model).config().teacher.model)
        pixels = "" if teacher else pixels_on_cpu(args.model, args.device)
        if pixels:
            print(fit(camera_expectation(pixels)))
        result = train(args.model, teacher=args.teacher, **overrides)
        if pixels and not getattr(result, "first_lap", None) and not getattr(result, "interrupted", False):
            print(fit(f"no evaluation lap yet: as expected so early for a {pixels} model on the CPU (see the note "
                       f"above); `racerlab train {shlex.quote(str(args.model))} --minutes {CAMERA_MINUTES}` goes on "
                       "from here"))
    where = shlex.quote(str(result.model_dir))
    print(f"model: {result.model_dir} (checkpoints/, training-simtrace/, metrics/)\n"
          f"next: `racerlab evaluate {where}` or `racerlab report {where}`")
    # Ctrl-C exits 130 wherever it lands (set-up or a later iteration), so `train && evaluate` stops
    return INTERRUPTED if getattr(result, "interrupted", False) else 0


INTERRUPTED = 130  # the shell's code for a command ended by SIGINT

# A camera model's first evaluation lap on the CPU, measured: README's tour (`racerlab init cam-model --sensor
# camera --max-speed 2`, `racerlab train cam-model --minutes 20`, 16 cars, droa car, lab_technical) on this
# project's shared 2-core machine, with other jobs running (load average 6-7), November 2026
CAMERA_UPDATE_S = (45, 98)  # one iteration's update, seconds (metrics.jsonl learn_seconds, iterations 1-7)
CAMERA_FIRST_LAP = (7, 10.1, 6.5)  # (iteration, minutes, load average) of the first evaluation lap (10.00 s)
CAMERA_MINUTES = 20  # what `init` and the note suggest for a camera model's first training
TAUGHT_MINUTES = 10  # ... and for one with a features teacher (docs/learner.md)


def fit(text: str) -> str:
    """80 columns, as the training's own lines (a long path or word stays whole, and a unit stays on its number's
    line: "100 %" and "8.53 s" are not split)."""
    import re
    import textwrap

    glued = re.sub(r"(\d) (%|s\b|m/s\b)", "\\1\u00a0\\2", text)  # textwrap does not break at a no-break space
    return textwrap.fill(glued, 80, subsequent_indent="  ", break_on_hyphens=False,
                         break_long_words=False).replace("\u00a0", " ")


def pixels_on_cpu(model, device: str | None) -> str:
    """The model's sensor ("camera", "stereo") when it learns from pixels and will train on the CPU; else ""."""
    from racerlab.model import ModelFolder

    folder = ModelFolder(model)
    run = folder.config().run
    # training.toml's observation, else the camera of model_metadata.json (FRONT_FACING_CAMERA, STEREO_CAMERAS)
    sees = (run.observation or str(folder.metadata().camera or "")).lower()
    sensor = "stereo" if "stereo" in sees else "camera" if "camera" in sees else ""
    if not sensor:
        return ""
    device = device or run.device
    if device.startswith("cuda"):
        return ""
    if device == "auto":
        import torch

        if torch.cuda.is_available():
            return ""
    return sensor


def camera_expectation(sensor: str) -> str:
    """What a pixel model's first minutes look like on a CPU, in measured numbers."""
    import os

    it, minutes, load = CAMERA_FIRST_LAP
    lo, hi = CAMERA_UPDATE_S
    return (f"note: a {sensor} model learns from pixels, here on the CPU ({os.cpu_count()} cores): on racerlab's "
            f"shared 2-core machine an iteration's update took {lo}-{hi} s and the first evaluation lap came at "
            f"iteration {it}, after {minutes:.0f} minutes (load average {load:.1f}); until then the eval % column "
            f"shows the progress. Give it {CAMERA_MINUTES} minutes or more (training resumes where it stopped), or "
            "a GPU.")


def run_clone(args) -> int:
    from racerlab.model import clone_model

    folder = clone_model(args.src, args.dst, args.checkpoint, args.reward, args.model_metadata, args.hyperparameters,
                         args.track)
    print(f"cloned {args.src} ({args.checkpoint} checkpoint) into {folder.path}; train it with "
          f"`racerlab train {shlex.quote(str(folder.path))}`")
    return 0
