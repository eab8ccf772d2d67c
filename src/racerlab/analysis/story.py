"""What a training changed, in a few lines a racer reads after a race (`training_story`): an early iteration's
in-training evaluation beside the raced checkpoint's and the race's laps, and when the best evaluation lap came
early and later laps were slower, why: the action space's top speed (`_capped`), or a reward that does not pay
for speed (`_why`); when later laps held it, what the reward's own line laps (`_held`). The quickstart prints it;
a report or the console can show the same lines.
"""

from __future__ import annotations

from pathlib import Path

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
        else:
            lines.append(_held(model, best, median, last))
    return lines


def _held(model: Path, best: tuple[float, int], median: float, last: int) -> str:
    """The best eval lap came early and the later evaluations drove it again: training found what its reward
    pays for early. With the racing_line template the reward's own line says how fast that is."""
    from racerlab.logs import BEST_LAP_NAME
    from racerlab.reward.templates import line_lap

    text = (f"the {BEST_LAP_NAME}, {best[0]:.2f} s, came at iteration {best[1]} of {last} and the later "
            f"evaluations held it (median {median:.2f} s over iterations {best[1] + 1}-{last})")
    try:
        source = (model / "reward_function.py").read_text()
    except OSError:
        source = ""
    lap = line_lap(source)
    if lap is not None:
        return (text + f": the reward pays most for following its racing line, whose own lap is {lap:.3f} s; "
                "a line with less margin (`racerlab init --line-margin`) leaves more to find")
    return text + ": training found early what its reward pays for"


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
