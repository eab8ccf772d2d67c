"""`racerlab quickstart`: the main job on built-in defaults.

Creates the default model folder if it is missing, trains it on the default track for a few
minutes, evaluates the best checkpoint (the fastest evaluation laps) under race rules (3 laps) and
draws the evaluation and the training curve, then says which checkpoint drove the laps, where
everything is and what to run next.
"""

from __future__ import annotations

from pathlib import Path

DEFAULT_MODEL = Path("racerlab-out") / "quickstart-model"  # racerlab.cli.OUT_DIR; the console lists it


def register(sub) -> None:
    p = sub.add_parser("quickstart", help="init → train → evaluate → pictures, on built-in defaults",
                       description="Create a model (if missing), train it on the default track, drive a lap "
                                   "with its best checkpoint and draw the results.")
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL, help=f"model folder (default {DEFAULT_MODEL})")
    p.add_argument("--track", default=None, help="track name or path (default: the bundled default track)")
    p.add_argument("--minutes", type=float, default=3.0, help="training time in minutes (default 3)")
    from racerlab.cli.model import QUICKSTART_MAX_SPEED

    p.add_argument("--max-speed", type=float, default=QUICKSTART_MAX_SPEED,
                   help=f"top speed of a new model's actions (default {QUICKSTART_MAX_SPEED:g}; `racerlab init` makes "
                        "1 m/s, the AWS console's default)")
    p.set_defaults(func=run)


def run(args) -> int:
    from racerlab.evaluate import evaluate
    from racerlab.model import ModelFolder, init_model
    from racerlab.train import train

    folder = ModelFolder(args.model)
    if not folder.metadata_path.is_file():
        # The quickstart shows the fastest laps training found: its best checkpoint is the one with the
        # fastest greedy evaluation laps, not AWS's default (highest mean progress, newest on ties), which
        # keeps a late, slower checkpoint once every evaluation episode completes its lap.
        init_model(folder.path, track=args.track, max_speed=args.max_speed, best_model_metric="laptime")
        from racerlab.cli.model import FEATURES_NOTE

        print(f"created model folder {folder.path}")
        print(FEATURES_NOTE)
    train(folder.path, minutes=args.minutes, tracks=[args.track] if args.track else None)
    res = evaluate(folder.path, track=args.track)
    print(res.report())
    out = folder.path / "quickstart"
    out.mkdir(exist_ok=True)
    lap_png, curve_png = out / "evaluation.png", out / "training.png"
    draw_lap(res, args.track or folder.config().track.names[0], lap_png)
    draw_curve(folder.path, curve_png)
    print(checkpoint_line(folder, res))
    for line in training_story(folder.path):
        print(line)
    print(f"results: model {folder.path} | evaluation {res.out_dir} | pictures {lap_png}, {curve_png}")
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


def training_story(model: Path) -> list[str]:
    """What training changed: the in-training evaluation of iteration 5 beside the last iteration's, and, when
    the best eval lap came early and later laps were slower, why (do the logged laps pay for speed?) and where
    to look next."""
    from racerlab.logs import BEST_LAP_NAME, best_eval_lap, metrics_jsonl_path, read_metrics_jsonl

    rows = [r for r in read_metrics_jsonl(metrics_jsonl_path(model)) if r.get("eval/mean_progress") is not None]
    if not rows:
        return []
    early = next((r for r in rows if r["iteration"] >= EARLY_ITERATION), rows[0])
    last = rows[-1]
    if last is early:
        return [f"iteration {last['iteration']}: {_eval_text(last)} (one evaluated iteration: nothing to compare)"]
    lines = [f"training: iteration {early['iteration']} {_eval_text(early)}; iteration {last['iteration']} (the "
             f"last) {_eval_text(last)}: {_change(early, last)}"]
    best = best_eval_lap(rows)
    late_lap = last.get("eval/best_lap")
    if best and best[1] is not None and late_lap is not None and late_lap > 1.02 * best[0] \
            and best[1] <= max(EARLY_ITERATION, last["iteration"] // 4):
        lines.append(f"the {BEST_LAP_NAME}, {best[0]:.2f} s, came at iteration {best[1]} of {last['iteration']}; "
                     f"later laps were slower. {_why(model)}")
        lines.append(f"see what a reward pays for on the laps already driven: `racerlab reward rescore {model} "
                     "--reward my_reward.py` (its table ranks the laps by lap time and by reward)")
    return lines


def _eval_text(row: dict) -> str:
    lap = row.get("eval/best_lap")
    progress = f"evaluation progress {row['eval/mean_progress']:.0f} %"
    return f"(lap {lap:.2f} s, {progress})" if lap is not None else f"(no lap, {progress})"


def _change(early: dict, last: dict) -> str:
    a, b = early.get("eval/best_lap"), last.get("eval/best_lap")
    if a is not None and b is not None:
        if abs(b - a) < 0.005:
            return "as fast"
        return f"{abs(b - a):.2f} s {'faster' if b < a else 'slower'}"
    if b is not None:
        return "it completes a lap, iteration {} did not".format(early["iteration"])
    if a is not None:
        return "it no longer completes a lap"
    pa, pb = early["eval/mean_progress"], last["eval/mean_progress"]
    return f"{abs(pb - pa):.0f} points of progress {'more' if pb >= pa else 'fewer'}"


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
    m = str(model)
    lines = [
        ("racerlab report " + m, f"then open {model / 'report.html'}: training, laps, track heatmaps"),
        (f"racerlab evaluate {m} --video", "race it again (3 laps) and write an MP4 of the laps"),
        (f"cp {model / 'reward_function.py'} my_reward.py", "a new reward: edit my_reward.py, then"),
        ("racerlab reward check my_reward.py --track " + _track_arg(model), "call it over the whole track"),
        (f"racerlab reward rescore {m} --reward my_reward.py", "how it scores the laps already driven"),
        (f"racerlab clone {m} my-model --reward my_reward.py && racerlab train my-model --minutes 5",
         "train with it"),
    ]
    width = max(len(c) for c, _ in lines)
    return "next:\n" + "\n".join(f"  {c.ljust(width)}  # {why}" for c, why in lines)


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
