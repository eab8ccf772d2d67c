"""`best_eval_lap`: the one meaning of "best lap" for a training, from metrics.jsonl entries."""

from __future__ import annotations

from racerlab.logs import best_eval_lap


def test_the_fastest_evaluation_lap_and_the_earliest_iteration_that_drove_it():
    rows = [{"iteration": 1, "eval/best_lap": None}, {"iteration": 2, "eval/best_lap": 9.4},
            {"iteration": 3, "eval/best_lap": 8.333}, {"iteration": 4, "eval/best_lap": 8.333},
            {"iteration": 5, "eval/best_lap": 9.2}]
    assert best_eval_lap(rows) == (8.333, 3)
    assert best_eval_lap(rows[:2]) == (9.4, 2) and best_eval_lap(rows[:1]) is None and best_eval_lap([]) is None


def test_the_running_record_of_the_newest_entry_is_enough():
    last = {"iteration": 50, "eval/best_lap": 9.2, "best/lap_time": 8.333, "best/lap_iteration": 4}
    assert best_eval_lap([last]) == (8.333, 4)  # the console reads only the file's tail


def test_a_record_without_its_iteration_is_not_mistaken_for_the_newest_lap():
    """A training resumed from a checkpoint written before best/lap_iteration existed: the record holds."""
    rows = [{"iteration": 4, "eval/best_lap": 8.333, "best/lap_time": 8.333},
            {"iteration": 50, "eval/best_lap": 9.2, "best/lap_time": 8.333, "best/lap_iteration": None}]
    assert best_eval_lap(rows) == (8.333, 4)
    assert best_eval_lap(rows[-1:]) == (8.333, None)
