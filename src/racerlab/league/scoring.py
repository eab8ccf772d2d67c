"""A submission's score from its evaluation's laps, and the leaderboard ordered from stored scores.

`score(laps, rules)` reads `evaluate`'s per-lap results (`Lap`: status, time with the penalties inside) and
applies the race's timing method (see `racerlab.league.rules`):

- `best_lap`: the fastest lap among the COMPLETED laps (DRoA took the minimum over every lap, finished or not);
  ranked with at least `min_laps` completed laps;
- `average_lap`: the smallest mean over `min_laps` consecutive completed laps, floored to whole milliseconds
  (`evaluate.results.best_consecutive_average`); ranked when such a run exists;
- `total_time`: every lap's elapsed time added; ranked only when all `laps` laps are completed.

The outcome is `ranked` (with the score in milliseconds), `not_ranked` (some laps, fewer than the race needs,
said with the laps it has) or `no_lap`. The leaderboard keeps each racer's best ranked submission; ties go to the
earlier submission (the smaller score first, then the earlier time of submitting, then the smaller id): one
order, used by every listing and by a racer's own rank.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from racerlab.evaluate import Lap
from racerlab.evaluate.results import best_consecutive_average
from racerlab.league.rules import Rules


@dataclass(frozen=True)
class Score:
    status: str  # ranked | not_ranked | no_lap
    score_ms: int | None
    laps_completed: int
    laps_driven: int
    off_track: int
    reason: str  # one line: what the racer reads beside the status

    def to_json(self) -> dict:
        return dict(self.__dict__)


def _ms_text(ms: int) -> str:
    return f"{ms / 1000:.3f} s"


def score(laps: list[Lap], rules: Rules) -> Score:
    """The race's figure for one evaluation's laps."""
    done = [lap for lap in laps if lap.completed]
    off = sum(lap.counts.get("off_track", 0) for lap in laps)
    base = {"laps_completed": len(done), "laps_driven": len(laps), "off_track": off}
    if not done:
        return Score("no_lap", None, **base, reason=f"no lap completed in {len(laps)} driven")
    ms, short = _figure(laps, done, rules)
    if ms is None:
        return Score("not_ranked", None, **base, reason=short)
    return Score("ranked", ms, **base, reason=f"{_words(rules)} {_ms_text(ms)} ({len(done)} of {rules.laps} laps)")


def _figure(laps: list[Lap], done: list[Lap], rules: Rules) -> tuple[int | None, str]:
    """(score in ms, "") or (None, why it is not ranked)."""
    n = rules.min_laps
    if rules.timing == "best_lap":
        if len(done) < n:
            return None, f"{len(done)} of the {n} completed laps the race needs (best lap {_ms_text(_best(done))})"
        return _best(done), ""
    if rules.timing == "average_lap":
        avg = best_consecutive_average(laps, n)
        if avg is None:
            return None, (f"{len(done)} laps completed, not {n} in a row (best lap {_ms_text(_best(done))}); "
                          f"the race ranks the best average over {n} consecutive laps")
        return int(round(avg * 1000)), ""
    if len(done) < rules.laps:
        return None, f"{len(done)} of {rules.laps} laps completed; a total-time race ranks only all laps completed"
    return sum(lap.time_ms for lap in laps), ""


def _best(done: list[Lap]) -> int:
    return min(lap.time_ms for lap in done)


def _words(rules: Rules) -> str:
    return {"best_lap": "best lap", "average_lap": f"best {rules.min_laps}-lap average",
            "total_time": "total time"}[rules.timing]


# ---- the leaderboard ------------------------------------------------------------------------------------------
@dataclass
class Entry:
    """One submission as the leaderboard sees it."""

    submission_id: int
    user_id: int
    alias: str
    score_ms: int | None
    submitted_at: float  # epoch seconds
    laps_completed: int = 0
    laps_driven: int = 0
    off_track: int = 0
    status: str = ""


def entry_key(e: Entry) -> tuple:
    """The one order of a leaderboard: score, then the earlier submission, then the smaller id."""
    return (e.score_ms if e.score_ms is not None else math.inf, e.submitted_at, e.submission_id)


def leaderboard(entries: list[Entry]) -> list[Entry]:
    """Each racer's best ranked entry, best first (`entry_key`); a later submission replaces a racer's row only
    when it is strictly better."""
    best: dict[int, Entry] = {}
    for e in entries:
        if e.score_ms is None:
            continue
        held = best.get(e.user_id)
        if held is None or entry_key(e) < entry_key(held):
            best[e.user_id] = e
    return sorted(best.values(), key=entry_key)
