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
    from racerlab.cli.model import fit
    from racerlab.evaluate import evaluate
    from racerlab.model import ModelFolder, init_model
    from racerlab.train import train

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


def checkpoint_line(folder, res) -> str:
    """Which checkpoint drove the evaluation's laps, and why that one."""
    checkpoints = folder.checkpoints()
    last = max((c.iteration for c in checkpoints), default=0)
    it = next((c.iteration for c in checkpoints if c.name == res.checkpoint), None)
    metric = {"laptime": "the fastest evaluation laps", "progress": "the highest evaluation progress",
              "reward": "the highest evaluation reward"}.get(folder.config().evaluation.best_model_metric, "")
    laps = f"laps 1-{len(res.laps)}" if len(res.laps) > 1 else "lap 1"
    where = f"iteration {it} of {last}" if it is not None else "a checkpoint"
    return (f"{laps} above: driven by checkpoint {res.checkpoint} ({where}, the best checkpoint: {metric} "
            f"during training)")


EARLY_ITERATION = 5  # the quickstart's model is compared with its own iteration 5
SLOWER = 1.02  # later laps this much slower than the best eval lap (their median) make the best "early"
AT_TOP_SPEED = 0.9  # a race that commands the top action speed on this share of its steps is capped by it


def training_story(model: Path, raced: str | None = None, race=None) -> list[str]:
    """What training changed: iteration 5's in-training evaluation beside the raced checkpoint's (`raced`, a
    checkpoint name; else the last evaluated iteration) and the race's laps (`race`, an EvaluationResult); when
    the best eval lap came early and the later laps were slower, why (the action space's top speed, or a reward
    that does not pay for speed) and where to look next."""
    import statistics

    from racerlab.logs import BEST_LAP_NAME, best_eval_lap, metrics_jsonl_path, read_metrics_jsonl
    from racerlab.model import CheckpointInfo

    rows = [r for r in read_metrics_jsonl(metrics_jsonl_path(model)) if r.get("eval/mean_progress") is not None]
    if not rows:
        return []
    early = next((r for r in rows if r["iteration"] >= EARLY_ITERATION), rows[0])
    info = CheckpointInfo.parse(raced) if raced else None  # <N>_Step-<S>.pt
    it = info.iteration if info else None
    final = next((r for r in rows if r["iteration"] == it), None) if it is not None else None
    name = f"iteration {final['iteration']} (the raced checkpoint)" if final else \
        f"iteration {rows[-1]['iteration']} (the last evaluated)"
    final = final or rows[-1]
    if final["iteration"] <= early["iteration"] and final is not rows[-1]:
        lines = [f"training: the raced checkpoint, iteration {final['iteration']} {_eval_text(final)}, is iteration "
                 f"{early['iteration']} or older: no later iteration's evaluation laps were faster"]
    elif final is early:
        lines = [f"training: iteration {final['iteration']} {_eval_text(final)}: one evaluated iteration, "
                 "nothing to compare"]
    else:
        lines = [f"what training changed, iteration {early['iteration']} -> {name}: {_change(early, final)}"]
    race_line = _race_text(race, early)
    if race_line:
        lines.append(race_line)
    best = best_eval_lap(rows)
    last = rows[-1]["iteration"]
    later = sorted(r["eval/best_lap"] for r in rows if best and best[1] is not None and r["iteration"] > best[1]
                   and r.get("eval/best_lap") is not None)
    if best and best[1] is not None and len(later) >= 3 and best[1] <= max(EARLY_ITERATION, last // 2):
        median = statistics.median(later)
        if median > SLOWER * best[0]:
            lines.append(f"the {BEST_LAP_NAME}, {best[0]:.2f} s, came at iteration {best[1]} of {last}; the later "
                         f"evaluation laps were slower (median {median:.2f} s over iterations {best[1] + 1}-{last}).")
            capped, why = _capped(model, race), _why(model)
            if capped:  # the first reason; the reward's is then what a faster action space will meet
                lines.append(capped)
                why = why.removeprefix("Why: ")
                why = "The reward: " + why[:1].lower() + why[1:] if why else ""
            if why:
                lines.append(why)
            lines.append(f"see what a reward pays for on the laps already driven: `racerlab reward rescore {model} "
                         "--reward my_reward.py` (its table ranks the laps by lap time and by reward)")
    return lines


def _race_text(race, early: dict) -> str:
    """The race's laps beside iteration `early`'s best evaluation lap."""
    laps = [lap.time for lap in getattr(race, "laps", []) if lap.completed]
    if not laps:
        return ""
    mean = sum(laps) / len(laps)
    text = f"the race above: {len(laps)} lap{'s' if len(laps) > 1 else ''}, {mean:.2f} s on average"
    ref = early.get("eval/best_lap")
    if ref is None:
        return text + f"; iteration {early['iteration']} drove no evaluation lap"
    if abs(mean - ref) < 0.005:
        return text + f", as fast as iteration {early['iteration']}'s best evaluation lap"
    return text + (f", {abs(mean - ref):.2f} s {'faster' if mean < ref else 'slower'} than iteration "
                   f"{early['iteration']}'s best evaluation lap ({ref:.2f} s)")


def _eval_text(row: dict) -> str:
    lap = row.get("eval/best_lap")
    progress = f"evaluation progress {row['eval/mean_progress']:.0f} %"
    return f"(lap {lap:.2f} s, {progress})" if lap is not None else f"(no lap, {progress})"


def _change(early: dict, final: dict) -> str:
    """What improved (or got worse) between two iterations' evaluations: the best lap and the progress."""
    a, b = early.get("eval/best_lap"), final.get("eval/best_lap")
    if a is not None and b is not None:
        lap = "as fast" if abs(b - a) < 0.005 else f"{abs(b - a):.2f} s {'faster' if b < a else 'slower'}"
        lap = f"best evaluation lap {a:.2f} -> {b:.2f} s ({lap})"
    elif b is not None:
        lap = f"best evaluation lap none -> {b:.2f} s (it completes a lap, iteration {early['iteration']} did not)"
    elif a is not None:
        lap = f"best evaluation lap {a:.2f} s -> none (it no longer completes a lap)"
    else:
        lap = "no evaluation lap in either"
    pa, pb = early["eval/mean_progress"], final["eval/mean_progress"]
    return f"{lap}; evaluation progress {pa:.0f} -> {pb:.0f} %"


def _capped(model: Path, race) -> str:
    """Whether the race drove at the action space's top speed nearly all the way: then faster laps need faster
    actions, not more training (the quickstart's 2 m/s model does so within a minute of training)."""
    import numpy as np

    from racerlab.errors import RacerlabError
    from racerlab.model import ModelFolder
    from racerlab.spec import MAX_SPEED

    trace = getattr(getattr(race, "run", None), "trace", None)  # the race's simtrace columns, as it drove them
    try:
        top = ModelFolder(model).metadata().actions.top_speed
    except (RacerlabError, OSError, ValueError, AttributeError):
        return ""
    if not trace:
        return ""
    speeds = np.asarray(trace["throttle"], dtype=float)[np.asarray(trace["episode_status"]) != "prepare"]
    if not speeds.size:
        return ""
    share = float(np.mean(speeds >= top - 1e-6))
    if share < AT_TOP_SPEED:
        return ""
    why = (f"Why: in the race above the car commanded its top speed, {top:g} m/s, on {100 * share:.0f} % of its "
           "steps: the action space, not training, sets the pace now; only a shorter line is left to find.")
    if top >= MAX_SPEED:
        return why + f" {MAX_SPEED:g} m/s is the simulator's cap."
    faster = min(top + 1, MAX_SPEED)
    return why + (f" For faster laps give it faster actions: `racerlab init NEW --max-speed {faster:g}` (a new "
                  "model), or `racerlab clone` with a model_metadata.json whose speeds are higher.")


def _why(model: Path) -> str:
    """Whether the training laps that took longer earned more reward (the rank correlation of lap time and
    episode reward over the completed training laps): a reward paid per step does, and then training has no
    reason to drive faster."""
    from racerlab.analysis.load import load_metrics
    from racerlab.errors import RacerlabError

    try:
        tm = load_metrics(model, "training")
    except (RacerlabError, ValueError):
        return ""
    if tm.empty or not {"phase", "episode_status"} <= set(tm.columns):  # no training episode logged yet
        return ""
    laps = tm[(tm["phase"] == "training") & (tm["episode_status"] == "Lap complete")]
    if len(laps) < 10 or laps["elapsed_time_in_milliseconds"].nunique() < 2:
        return ""
    rho = laps["elapsed_time_in_milliseconds"].corr(laps["reward_score"], method="spearman")
    if rho != rho:  # NaN: every lap earned the same
        return ""
    how = f"rank correlation {rho:+.2f} between lap time and episode reward over {len(laps)} training laps"
    if rho > 0.1:
        return (f"Why: slower laps earned more reward ({how}): a reward paid at every step pays for more steps, "
                "so training learns to take longer; pay for progress per step or for the lap time instead.")
    if rho > -0.1:
        return (f"Why: faster laps earned no more reward than slower ones ({how}), so training had no reason to "
                "keep them.")
    if rho > -0.5:
        return (f"Why: faster laps earned only a little more reward ({how}): the reward pays mostly for something "
                "else (the centre line, the heading), and training followed what it pays for.")
    return (f"Faster laps earned clearly more reward ({how}), yet the greedy laps slowed: compare what the reward "
            "pays per lap below.")


def next_steps(model: Path) -> str:
    """What a newcomer runs next: look at the report, evaluate again, try a new reward."""
    import textwrap

    m = str(model)
    lines = [
        ("racerlab report " + m, f"then open {model / 'report.html'}: training, laps, track heatmaps"),
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


def draw_lap(res, track, path: Path) -> None:
    """The evaluation's path on the track, coloured by the speed derived from positions."""
    import numpy as np
    import pandas as pd
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    from racerlab.spec import STEP_S
    from racerlab.track import load as load_track
    from racerlab.track.plot import draw_track

    df = pd.read_csv(res.files["simtrace"])
    xy = df[["X", "Y"]].to_numpy()
    fig = Figure(figsize=(9, 7))
    ax = fig.add_subplot()
    draw_track(load_track(track), ax=ax, waypoint_numbers=False)
    step = np.hypot(*np.diff(xy, axis=0).T)
    keep = step < 0.5  # no line across a reset after an off-track
    segs = np.stack([xy[:-1], xy[1:]], axis=1)[keep]
    lc = LineCollection(segs, array=(step / STEP_S)[keep], cmap="plasma", linewidths=2.0, zorder=5)
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed (m/s)", shrink=0.7)
    ax.set_title(f"{res.model} ({res.checkpoint}) on {res.track}: {res.text}")
    fig.savefig(path, dpi=120, bbox_inches="tight")


def draw_curve(model: Path, path: Path) -> None:
    """The report's training-progress figure (reward, completion, lap times, entropy per iteration)."""
    from racerlab.analysis import load
    from racerlab.analysis.episodes import episode_summary, iteration_summary, run_metrics, step_kinematics
    from racerlab.analysis.plots import save_png, training_progress
    from racerlab.analysis.report import count_iterations_from_one

    df = load(model)
    its = iteration_summary(episode_summary(df, step_kinematics(df)), *run_metrics(model))
    count_iterations_from_one(its=its)  # as the console printed them
    save_png(training_progress(its, title=f"{model.name}: training progress"), path)
