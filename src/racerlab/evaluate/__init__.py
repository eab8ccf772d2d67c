"""Evaluation under race rules: trials, continuous laps, penalties and resets, race results, videos.

    >>> from racerlab.evaluate import evaluate, race
    >>> res = evaluate("my-model", trials=3, continuous=True, off_track_penalty=5.0)
    >>> print(res.report())                  # each lap's time, off-tracks and resets, best lap, result
    >>> res.text                             # "3 laps, average 9.613 s"
    >>> board = race(["a", "b", "c"], track="reInvent2019_track")
    >>> print(board.table())
    >>> board = head_to_model("a", "b")      # both on the track at once, each seeing the other

Parts: `rules` (RaceRules, where a car is put back), `runner` (driving one car under the rules),
`results` (laps, DeepRacer's ranking numbers), `api` (model folders in, evaluation folders out),
`race` (leaderboards), `video` (MP4 of a run).
"""

from racerlab.evaluate.api import EvaluationResult, evaluate
from racerlab.evaluate.race import Leaderboard, RaceCancelled, head_to_model, race
from racerlab.evaluate.results import Lap, RaceResult, race_result
from racerlab.evaluate.rules import RaceRules
from racerlab.evaluate.runner import EvalRun, run_evaluation, run_head_to_model

__all__ = ["EvalRun", "EvaluationResult", "Lap", "Leaderboard", "RaceCancelled", "RaceResult", "RaceRules", "evaluate",
           "head_to_model", "race", "race_result", "run_evaluation", "run_head_to_model"]
