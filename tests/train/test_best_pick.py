"""Which checkpoint is the best one: AWS's rule for progress and reward, and for lap time the newest checkpoint
within one step in one lap of the fastest mean lap so far (issue 32: a plateaued quickstart raced checkpoint 318
of 932 because its evaluation happened to draw one lap a step faster there)."""

from __future__ import annotations

import math

import pytest

from racerlab.train.evaluation import EvalEpisode, laptime_tie_ms, pick_best

DT = 1 / 15


def _lap(steps: int | None) -> EvalEpisode:
    done = steps is not None
    return EvalEpisode(0.0, "lap_complete" if done else "off_track", steps or 40, 100.0 if done else 50.0, 1.0,
                       steps * DT if done else math.nan, 0.0, 1.0)


def _run(metric, values, tie=0.0):
    """The iteration (1-based) kept after each value in turn."""
    kept, best, floor, out = None, None, None, []
    for i, v in enumerate(values, 1):
        keep, floor = pick_best(metric, v, best, floor, tie)
        if keep:
            kept, best = i, v
        out.append(kept)
    return out


def test_the_tie_is_one_step_in_one_of_the_evaluations_laps():
    assert laptime_tie_ms([_lap(78)] * 5, DT) == pytest.approx(13.333, abs=1e-3)  # 66.67 ms / 5 laps
    assert laptime_tie_ms([_lap(78)] * 4, DT) == pytest.approx(16.667, abs=1e-3)
    assert laptime_tie_ms([], DT) == pytest.approx(66.667, abs=1e-3)


def test_lap_time_keeps_the_newest_checkpoint_within_a_step_of_the_fastest():
    q = 1000 / 15 / 5  # one step in one of 5 laps
    base = 5200.0 + 2 * q  # laps of 78 and 79 steps, as the quickstart's plateau
    values = [999_999, 5466.7, base, base + 2 * q, base - q, base, base + q, base + 3 * q]
    assert _run("laptime", values, tie=q + 1e-6) == [1, 2, 3, 3, 5, 6, 6, 6]
    # the floor is the fastest mean so far, not the kept checkpoint's own: ties never drift slower step by step
    assert _run("laptime", [5300.0, 5300.0 + q, 5300.0 + 2 * q, 5300.0 + 3 * q], tie=q + 1e-6) == [1, 2, 2, 2]
    # without a tie the old rule: equal values only
    assert _run("laptime", values) == [1, 2, 3, 3, 5, 5, 5, 5]


def test_progress_and_reward_keep_aws_rule():
    assert _run("progress", [50.0, 100.0, 90.0, 100.0]) == [1, 2, 2, 4]  # the newer on ties (>=)
    assert _run("reward", [3.0, 2.0, 3.0], tie=100.0) == [1, 1, 3]  # a tie width means nothing here
    keep, floor = pick_best("progress", 10.0, None)
    assert keep and floor is None


def test_an_iteration_without_evaluation_keeps_the_best():
    assert _run("laptime", [5300.0, math.nan, 5310.0], tie=13.4) == [1, 1, 3]


def test_a_changed_best_model_metric_picks_anew_instead_of_reading_the_old_rules_best(tmp_path):
    """Issue 45: a model trained with best_model_metric = "progress" and switched to "laptime" read its stored
    progress as a lap time in ms; no lap beat it, and the best checkpoint stayed where the old rule left it."""
    import re

    from racerlab.model import init_model
    from racerlab.train import train

    folder = init_model(tmp_path / "m", track="lab_technical", max_speed=2.0)
    folder.write_hyperparameters(folder.hyperparameters().replace(num_episodes_between_training=2))
    text = re.sub(r"(?m)^max_episode_steps = .*$", "max_episode_steps = 150", folder.config_path.read_text())
    folder.config_path.write_text(text)
    first = train(folder.path, iterations=2, progress=False, num_cars=2)
    assert first.best_rule == "progress" and first.best_metric <= 100.0  # a progress, in %
    folder.config_path.write_text(text.replace('best_model_metric = "progress"', 'best_model_metric = "laptime"'))
    r = train(folder.path, iterations=2, progress=False, num_cars=2)
    assert r.best_rule == "laptime" and r.best_checkpoint.startswith(("3_", "4_"))  # picked by lap time now
    assert r.best_metric == 999_999  # no lap: AWS's unfinished lap (train.evaluation.UNFINISHED_LAP_MS)
    said = [n for n in r.notes if "best_model_metric is laptime" in n]
    assert len(said) == 1 and f"({first.best_checkpoint}) was picked by progress" in said[0]
