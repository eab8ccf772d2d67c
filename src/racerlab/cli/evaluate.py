"""`racerlab evaluate MODEL` and `racerlab race A B C`: race-rule evaluations and leaderboards."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _rule_flags(p) -> None:
    from racerlab import spec

    p.add_argument("--track", help="track name or path (default: the (first) model's training track)")
    p.add_argument("--trials", type=int, default=spec.EVAL_TRIALS,
                   help=f"laps (continuous) or trials to drive (default {spec.EVAL_TRIALS})")
    p.add_argument("--continuous", action=argparse.BooleanOptionalAction, default=True,
                   help="drive the trials as consecutive laps of one episode (default) or each from the start line")
    p.add_argument("--off-track-penalty", type=float, default=spec.EVAL_OFF_TRACK_PENALTY_S, metavar="S",
                   help=f"seconds held after an off-track or reversal (default {spec.EVAL_OFF_TRACK_PENALTY_S:g}, "
                        "as DRfC)")
    p.add_argument("--collision-penalty", type=float, default=spec.EVAL_COLLISION_PENALTY_S, metavar="S",
                   help=f"seconds held after a crash (default {spec.EVAL_COLLISION_PENALTY_S:g})")
    p.add_argument("--max-resets", type=int, default=spec.EVAL_MAX_RESETS, metavar="N",
                   help=f"resets per episode; the next incident ends it (default {spec.EVAL_MAX_RESETS})")
    p.add_argument("--enable-mercy-reset", action="store_true",
                   help="simapp's mercy reset: the Nth crash in a row into the same box (--max-resets-after-crash) "
                        "restarts the car --reset-ahead-dist ahead of the box instead of behind it")
    p.add_argument("--max-resets-after-crash", type=int, default=spec.EVAL_MAX_RESETS_AFTER_CRASH, metavar="N",
                   help=f"default {spec.EVAL_MAX_RESETS_AFTER_CRASH}, as the simapp")
    p.add_argument("--reset-ahead-dist", type=float, default=spec.EVAL_RESET_AHEAD_DIST_M, metavar="M",
                   help=f"m of centre line (default {spec.EVAL_RESET_AHEAD_DIST_M:g})")
    p.add_argument("--checkpoint", default="best", help="best (default), last or an iteration number")
    p.add_argument("--reverse", action="store_true", help="drive the track the other way round")
    p.add_argument("--ranking-laps", type=int, default=3, metavar="N",
                   help="consecutive completed laps whose best average ranks a model (default 3)")
    p.add_argument("--video", action="store_true", help="also write an MP4 of the run (evaluation.mp4)")
    p.add_argument("--device", default="cpu", help="torch device for the network (default cpu)")


# the [race] keys of training.toml as flags (DRfC's names): (key, type, help); booleans take --x / --no-x
RACE_FLAGS = (
    ("race_type", str, "time_trial, object_avoidance, head_to_bot or head_to_model (the model against itself; "
                  "default: the model's training.toml [race])"),
    ("number_of_obstacles", int, "evenly spaced boxes"),
    ("obstacle_type", str, "box_obstacle, deepracer_box_obstacle or amazon_box_obstacle"),
    ("randomize_obstacle_locations", bool, "re-draw the boxes between their neighbours, random lane"),
    ("object_positions", str, "fixed boxes as 'fraction,lane;...' (lane 1 inner, -1 outer), e.g. '0.25,1;0.5,-1'"),
    ("min_distance_between_obstacles", float, "%% of the lap"),
    ("number_of_bot_cars", int, "bot cars (head_to_bot)"),
    ("randomize_bot_car_locations", bool, "re-draw the bots between their neighbours, random lane"),
    ("bot_car_speed", float, "m/s"),
    ("is_lane_change", bool, "bots change lanes"),
    ("lower_lane_change_time", float, "s"),
    ("upper_lane_change_time", float, "s"),
    ("lane_change_distance", float, "m"),
    ("min_distance_between_bot_cars", float, "m"),
    ("penalty_seconds", float, "s a bot waits after running into the car"),
)


def _race_flags(p) -> None:
    g = p.add_argument_group("race", "override keys of the model's training.toml [race] (DRfC's names)")
    for key, kind, text in RACE_FLAGS:
        flag = "--" + key.replace("_", "-")
        if kind is bool:
            g.add_argument(flag, dest=f"race_{key}", action=argparse.BooleanOptionalAction, default=None, help=text)
        else:
            g.add_argument(flag, dest=f"race_{key}", type=kind, default=None, metavar=kind.__name__.upper(),
                           help=text)


def simulator_flag(p) -> None:
    """--simulator: whose car drives (default the model's training.toml [car])."""
    from racerlab.spec import SIMULATORS

    p.add_argument("--simulator", choices=SIMULATORS, default=None,
                   help="drive the car of this simulator (droa: DeepRacer on AWS / DRfC >= 6; console: the AWS "
                        "console / DRfC <= 5; default: the model's training.toml [car], else droa)")


def race_overrides(args) -> dict:
    """The [race] keys given as flags ({} when none): `race_type` is the table's `type`, `object_positions`
    the ';'-separated "fraction,lane" pairs DRfC's DR_OA_OBJECT_POSITIONS takes."""
    out = {}
    for key, _, _ in RACE_FLAGS:
        value = getattr(args, f"race_{key}", None)
        if value is None:
            continue
        if key == "object_positions":
            value = [v.strip() for v in value.split(";") if v.strip()]
        out["type" if key == "race_type" else key] = value
    return out


def register(sub) -> None:
    p = sub.add_parser("evaluate", help="evaluate a model under race rules (trials, penalties, resets)",
                       description="Drive a model's checkpoint with greedy actions under AWS race rules (DRfC "
                                   "defaults: 3 continuous laps, 5 s off-track penalty, 100 resets) and write the "
                                   "evaluation simtrace, EvalMetrics.json and summary.json into the model folder.")
    p.add_argument("model", type=Path, help="model folder")
    _rule_flags(p)
    _race_flags(p)
    p.add_argument("--tracks-from", type=Path, metavar="DIR",
                   help="generalisation: drive one lap (no resets) on --count tracks of DIR (.npy files) the model "
                        "never trained on and print the share it completes")
    p.add_argument("--count", type=int, default=20, help="tracks taken from --tracks-from (default 20)")
    p.add_argument("--json", type=Path, metavar="FILE", help="with --tracks-from: also write the result as JSON")
    p.add_argument("--picture", type=Path, metavar="FILE",
                   help="with --tracks-from: the picture of the tracks lapped and missed (default "
                        "MODEL/generalisation/tracks.png; under --randomise also tracks_randomised.png beside it)")
    p.add_argument("--no-limits", action="store_true",
                   help="with --tracks-from: leave out each track's theoretical limit (solved once per track and "
                        "car, 2-12 s each, then cached) and the laps' ratio to it")
    p.add_argument("--randomise", action="store_true",
                   help="drive under the [randomise] settings of the model's training.toml; with --tracks-from "
                        "the tracks are driven with and without it and the drop in lap completion is printed")
    p.add_argument("--speed-scale", type=float, metavar="F",
                   help="the physical car's max-speed setting as a fraction: speeds are taken relative to the "
                        "action space's top speed and scaled by F (default 1)")
    p.add_argument("--top-speed", type=float, metavar="MPS",
                   help="m/s that the action space's top speed stands for (default: its own value)")
    simulator_flag(p)
    p.set_defaults(func=run_evaluate)

    p = sub.add_parser("race", help="evaluate several models under the same rules and rank them",
                       description="Evaluate every model on one track under the same race rules and print a "
                                   "leaderboard ranked as DeepRacer ranks (best average of consecutive laps).")
    p.add_argument("models", type=Path, nargs="+", help="model folders")
    _rule_flags(p)
    _race_flags(p)
    p.add_argument("--out", type=Path,
                   help="leaderboard JSON file (default race-<stamp>.json in the first model's folder)")
    p.add_argument("--head-to-model", action="store_true",
                   help="race two models on the track at once, each seeing the other (crashes between them count)")
    simulator_flag(p)
    p.set_defaults(func=run_race)


def _rules(args):
    from racerlab.evaluate import RaceRules

    return RaceRules(trials=args.trials, continuous=args.continuous, off_track_penalty=args.off_track_penalty,
                     collision_penalty=args.collision_penalty, max_resets=args.max_resets, reverse=args.reverse,
                     enable_mercy_reset=args.enable_mercy_reset, max_resets_after_crash=args.max_resets_after_crash,
                     reset_ahead_dist=args.reset_ahead_dist)


def _print_lap(lap) -> None:
    how = f"{lap.time:.3f} s" if lap.completed else f"{lap.status.replace('_', ' ')} at {lap.progress:.1f} %"
    print(f"  lap {lap.trial}: {how}", file=sys.stderr, flush=True)


def _settings(args):
    """(plain, randomised) settings the flags ask for: the speed mapping alone (None when not asked), and
    the model's [randomise] table with that mapping (None without --randomise)."""
    from dataclasses import replace

    from racerlab.errors import RacerlabError
    from racerlab.model import ModelFolder
    from racerlab.model.config import RandomiseSettings

    if (args.speed_scale is not None and args.speed_scale <= 0) or (args.top_speed or 0) < 0:
        raise RacerlabError("--speed-scale must be > 0 and --top-speed >= 0")
    speed = {"speed_scale": args.speed_scale or 1.0, "top_speed": args.top_speed or 0.0}
    plain = RandomiseSettings(**speed)
    if not args.randomise:
        return (plain if plain.active else None), None
    folder = ModelFolder(args.model)
    r = folder.config().randomise
    if not r.active:
        raise RacerlabError(f"{folder.config_path}: [randomise] sets no option; add some (e.g. camera_noise = 4, "
                            "latency_steps = 1) or leave out --randomise")
    if plain.active:
        r = replace(r, **speed)
    return (plain if plain.active else None), r


def run_generalisation(args) -> int:
    from racerlab.evaluate.generalise import evaluate_tracks, held_out_tracks, save_picture
    from racerlab.logs import atomic_write_json, finite_json
    from racerlab.model import ModelFolder

    plain, randomised = _settings(args)
    paths = held_out_tracks(args.tracks_from, args.count, exclude=ModelFolder(args.model).config().track.names)

    def done(outcome, is_randomised):
        how = "randomised " if is_randomised else ""
        print(f"  {how}{outcome.track}: {outcome.laps}/{outcome.trials} laps, best progress "
              f"{outcome.best_progress:.0f} %", file=sys.stderr, flush=True)

    res = evaluate_tracks(args.model, paths, trials=args.trials, checkpoint=args.checkpoint, device=args.device,
                          plain=plain, randomise=randomised, on_track=done, limits=not args.no_limits)
    print(res.report())
    picture = args.picture or Path(args.model) / "generalisation" / "tracks.png"
    written = [save_picture(res, picture)]
    if randomised is not None:
        written.append(save_picture(res, picture.with_name(f"{picture.stem}_randomised{picture.suffix}"),
                                    randomised=True))
    if args.json:
        atomic_write_json(args.json, finite_json(res.to_json()), indent=2)
        written.append(args.json)
    print(f"written to {', '.join(str(p) for p in written)}")
    return 0


def run_evaluate(args) -> int:
    from racerlab.cli import require_models

    require_models(args.model)  # before the simulator and torch load: a typo is answered at once
    from racerlab.evaluate import evaluate

    if args.tracks_from:
        return run_generalisation(args)
    plain, randomised = _settings(args)
    res = evaluate(args.model, track=args.track, rules=_rules(args), checkpoint=args.checkpoint, video=args.video,
                   ranking_laps=args.ranking_laps, device=args.device, progress=True, on_lap=_print_lap,
                   race=race_overrides(args) or None, randomise=randomised or plain, car=args.simulator)
    print(res.report())
    names = ", ".join(str(p.relative_to(res.out_dir)) for p in res.files.values())
    print(f"written to {res.out_dir}: {names}")
    return 0


def run_race(args) -> int:
    from racerlab.cli import require_models
    from racerlab.errors import RacerlabError

    require_models(*args.models)
    from racerlab.evaluate import head_to_model, race
    from racerlab.evaluate.race import stopped_text

    finished = []

    def done(res):
        finished.append(res.model)
        print(f"{res.model}: {res.text}", file=sys.stderr, flush=True)

    common = dict(track=args.track, rules=_rules(args), checkpoint=args.checkpoint, ranking_laps=args.ranking_laps,
                  out=args.out, video=args.video, progress=True, on_result=done, device=args.device, car=args.simulator)
    if args.head_to_model:
        if len(args.models) != 2:
            raise RacerlabError(f"race --head-to-model races two models, got {len(args.models)}; name two folders")
        if race_overrides(args):
            raise RacerlabError("race --head-to-model puts only the two cars on the track; drop the [race] flags")
    try:
        if args.head_to_model:
            board = head_to_model(*args.models, **common)
        else:
            board = race(args.models, race=race_overrides(args) or None, **common)
    except KeyboardInterrupt:  # Ctrl-C: one line saying what stays, exit status 130 as for any interrupted command
        print(f"racerlab: {stopped_text('interrupted', finished, len(args.models))}", file=sys.stderr)
        return 130
    r = board.rules
    how = "head to model, " if args.head_to_model else ""
    from racerlab.evaluate.results import trials_text

    print(f"race on {board.track}: {how}{trials_text(r.trials, r.continuous)}, off-track "
          f"penalty {r.off_track_penalty:g} s, up to {r.max_resets} resets")
    print(board.table())
    print(f"leaderboard written to {board.path}")
    return 0
