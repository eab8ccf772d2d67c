"""`racerlab quickstart`: the main job on built-in defaults.

Creates the default model folder if it is missing (continuous actions up to 4 m/s and the racing_line
reward: the path of the track's limit 0.1 m over the borders, at the speeds the car can hold there, so that
training has laps to get faster on for its whole run), trains it on the default track for a few minutes,
evaluates the best checkpoint (the fastest evaluation laps) under race rules (3 laps) and draws the
evaluation and the training curve, then says which checkpoint drove the laps, what training changed
(iteration 5's evaluation laps beside the raced checkpoint's and the race's; when the best lap came early,
why: the action space's top speed, or a reward that does not pay for speed), where everything is and what to
run next.
"""

from __future__ import annotations

import math
from pathlib import Path

DEFAULT_MODEL = Path("racerlab-out") / "quickstart-model"  # racerlab.cli.OUT_DIR; the console lists it
DEFAULT_MINUTES = 3.0
WIDTH = 80  # the quickstart's own lines fit a terminal of the default width


def register(sub) -> None:
    p = sub.add_parser("quickstart", help="init → train → evaluate → pictures, on built-in defaults",
                       description="Create a model (if missing), train it on the default track, drive a lap "
                                   "with its best checkpoint and draw the results.")
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL, help=f"model folder (default {DEFAULT_MODEL})")
    p.add_argument("--track", default=None, help="track name or path (default: the bundled default track)")
    p.add_argument("--minutes", type=float, default=None,
                   help=f"training time in minutes (default {DEFAULT_MINUTES:g}, or none with --iterations)")
    p.add_argument("--iterations", type=int, default=None,
                   help="stop after this many training iterations (with --minutes: whichever comes first)")
    from racerlab.cli.model import QUICKSTART_ACTIONS, QUICKSTART_MAX_SPEED, QUICKSTART_REWARD
    from racerlab.reward import TEMPLATES as REWARD_TEMPLATES

    p.add_argument("--max-speed", type=float, default=QUICKSTART_MAX_SPEED,
                   help=f"top speed of a new model's actions (default {QUICKSTART_MAX_SPEED:g}; `racerlab init` makes "
                        "1 m/s, the AWS console's default)")
    p.add_argument("--action-space", choices=["discrete", "continuous"], default=QUICKSTART_ACTIONS,
                   help=f"a new model's action space (default {QUICKSTART_ACTIONS})")
    p.add_argument("--reward", choices=list(REWARD_TEMPLATES), default=QUICKSTART_REWARD,
                   help=f"a new model's reward template, as `racerlab init --reward` (default {QUICKSTART_REWARD})")
    p.set_defaults(func=run)


def run(args) -> int:
    from racerlab.analysis.figures import draw_curve, draw_lap
    from racerlab.analysis.story import training_story
    from racerlab.cli.model import fit
    from racerlab.evaluate import evaluate
    from racerlab.model import ModelFolder, init_model
    from racerlab.train import train

    check_args(args)
    folder = ModelFolder(args.model)
    if not folder.metadata_path.is_file():
        # The quickstart shows the fastest laps training found: its best checkpoint is the one with the
        # fastest greedy evaluation laps, not AWS's default (highest mean progress, newest on ties), which
        # keeps a late, slower checkpoint once every evaluation episode completes its lap.
        init_model(folder.path, track=args.track, max_speed=args.max_speed, action_space=args.action_space,
                   best_model_metric="laptime")
        from racerlab.cli.model import FEATURES_NOTE, write_template

        write_template(folder, args.reward)

        print(f"created model folder {folder.path}")
        print(FEATURES_NOTE)
    minutes = args.minutes if args.minutes is not None else (0 if args.iterations else DEFAULT_MINUTES)
    train(folder.path, minutes=minutes, iterations=args.iterations, tracks=[args.track] if args.track else None)
    res = evaluate(folder.path, track=args.track)
    print(res.report())
    out = folder.path / "quickstart"
    out.mkdir(exist_ok=True)
    lap_png, curve_png = out / "evaluation.png", out / "training.png"
    draw_lap(res, args.track or folder.config().track.names[0], lap_png)
    draw_curve(folder.path, curve_png)
    for line in [checkpoint_line(folder, res), *training_story(folder.path, res.checkpoint, res),
                 f"results: model {folder.path} | evaluation {res.out_dir} | pictures {lap_png}, {curve_png}"]:
        print(fit(line))
    print(next_steps(folder.path))
    return 0


def check_args(args) -> None:
    """Everything the command line says, checked before a folder is made: one line naming the option."""
    from racerlab.errors import RacerlabError

    if args.model.exists() and not args.model.is_dir():
        raise RacerlabError(f"--model {args.model}: a file, not a model folder; give a folder (new or a model's)")
    for flag, value in (("--minutes", args.minutes), ("--iterations", args.iterations)):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise RacerlabError(f"{flag} must be a number >= 0 (0 = no limit), got {value}")
    if not math.isfinite(args.max_speed):
        raise RacerlabError(f"--max-speed {args.max_speed}: give a speed in m/s, e.g. --max-speed 2")


def checkpoint_line(folder, res) -> str:
    """Which checkpoint drove the evaluation's laps, and why that one."""
    checkpoints = folder.checkpoints()
    last = max((c.iteration for c in checkpoints), default=0)
    it = next((c.iteration for c in checkpoints if c.name == res.checkpoint), None)
    metric = {"laptime": "the fastest evaluation laps during training, the newest of those within a step",
              "progress": "the highest evaluation progress during training",
              "reward": "the highest evaluation reward during training"}.get(
        folder.config().evaluation.best_model_metric, "")
    laps = f"laps 1-{len(res.laps)}" if len(res.laps) > 1 else "lap 1"
    where = f"iteration {it} of {last}" if it is not None else "a checkpoint"
    return f"{laps} above: driven by checkpoint {res.checkpoint} ({where}, the best checkpoint: {metric})"


def next_steps(model: Path) -> str:
    """What a newcomer runs next: look at the report, evaluate again, try a new reward."""
    import textwrap

    from racerlab.analysis.report import REPORT_NAME

    m = str(model)
    lines = [
        ("racerlab report " + m, f"then open {model / REPORT_NAME}: training, laps, track heatmaps"),
        (f"racerlab evaluate {m} --video", "race it again (3 laps) and write an MP4 of the laps"),
        (f"cp {model / 'reward_function.py'} my_reward.py", "a new reward: edit my_reward.py, then"),
        ("racerlab reward check my_reward.py --track " + _track_arg(model), "call it over the whole track"),
        (f"racerlab reward rescore {m} --reward my_reward.py", "how it scores the laps already driven"),
        (f"racerlab clone {m} my-model --reward my_reward.py", "a new model from this one's best checkpoint, with it"),
        ("racerlab train my-model --minutes 5", "train with it"),
    ]
    width = max(len(c) for c, _ in lines)
    if 2 + width + 4 + max(len(why) for _, why in lines) <= WIDTH:
        return "next:\n" + "\n".join(f"  {c.ljust(width)}  # {why}" for c, why in lines)
    # too wide for one line each (a long model path): the reason, wrapped, above its command, which stays whole
    # to be copied
    return "next:\n" + "\n".join(
        textwrap.fill(why, WIDTH, initial_indent="  # ", subsequent_indent="  #   ", break_long_words=False,
                      break_on_hyphens=False) + f"\n  {c}" for c, why in lines)


def _track_arg(model: Path) -> str:
    from racerlab.errors import RacerlabError
    from racerlab.model import ModelFolder

    try:
        return ModelFolder(model).config().track.names[0]
    except (RacerlabError, IndexError):
        return "lab_technical"
