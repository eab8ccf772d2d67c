"""Laps and race results: one record per lap, the numbers DeepRacer ranks by, and how they read.

Ranking follows DeepRacer on AWS (`ModelPerformanceMetricsHelper.ts`, facts §8): the best lap is
the fastest completed lap; the ranking average is the smallest mean over any `ranking_laps`
consecutive trials that were all completed (the classic console ranked by the first three
consecutive laps), floored to whole milliseconds; `completed_streak` is the longest run of
completed laps. Lap times are those of `EvalMetrics.json` (whole milliseconds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from racerlab.evaluate.rules import INCIDENTS
from racerlab.spec import STATUS_LABELS

DEFAULT_RANKING_LAPS = 3


def _zero_counts() -> dict[str, int]:
    return dict.fromkeys(INCIDENTS, 0)


@dataclass
class Lap:
    """One trial: a lap from its start (the reset, or the previous lap's completion) to its end."""

    trial: int  # 1-based, EvalMetrics `trial`
    status: str  # how it ended, as a simtrace status: lap_complete, off_track, reversed, ..., time_up
    start_time: float  # simulated time, s
    end_time: float
    progress: float  # % reached
    counts: dict[str, int] = field(default_factory=_zero_counts)  # incidents in this lap
    rows: int = 0  # simtrace rows (steps) of this lap, pause rows included

    @property
    def completed(self) -> bool:
        return self.status == "lap_complete"

    @property
    def time_ms(self) -> int:
        """Elapsed simulated time in whole milliseconds, penalties included (AWS elapsed_time_in_milliseconds)."""
        return int(round((self.end_time - self.start_time) * 1000))

    @property
    def time(self) -> float:
        return self.time_ms / 1000

    @property
    def resets(self) -> int:
        return sum(self.counts.values())

    def eval_metrics_entry(self) -> dict:
        """This lap as an `EvalMetrics.json` entry (AWS schema, facts §7)."""
        return {"completion_percentage": int(min(self.progress, 100.0)),
                "metric_time": int(round(self.end_time * 1000)), "start_time": int(round(self.start_time * 1000)),
                "elapsed_time_in_milliseconds": self.time_ms,
                "episode_status": STATUS_LABELS.get(self.status, self.status),
                "crash_count": self.counts["crashed"], "immobilized_count": self.counts["immobilized"],
                "off_track_count": self.counts["off_track"], "reversed_count": self.counts["reversed"],
                "reset_count": self.resets, "trial": self.trial}

    def to_json(self) -> dict:
        return {"trial": self.trial, "status": self.status, "completed": self.completed,
                "lap_time": self.time if self.completed else None, "elapsed": self.time,
                "progress": round(self.progress, 4), "start_time": self.start_time, "end_time": self.end_time,
                "off_track": self.counts["off_track"], "crashed": self.counts["crashed"],
                "immobilized": self.counts["immobilized"], "reversed": self.counts["reversed"],
                "resets": self.resets, "steps": self.rows}


def best_consecutive_average(laps: list[Lap], window: int) -> float | None:
    """Smallest mean lap time (s, floored to whole ms) over `window` consecutive completed laps; None
    when no such run exists."""
    if window < 1:
        raise ValueError("window must be >= 1")
    best = None
    for i in range(len(laps) - window + 1):
        run = laps[i:i + window]
        if all(lap.completed for lap in run):
            avg = math.floor(sum(lap.time_ms for lap in run) / window)
            best = avg if best is None else min(best, avg)
    return None if best is None else best / 1000


def completed_streak(laps: list[Lap]) -> int:
    """Longest run of consecutive completed laps."""
    best = run = 0
    for lap in laps:
        run = run + 1 if lap.completed else 0
        best = max(best, run)
    return best


def counted(n: int, noun: str) -> str:
    """"1 trial", "3 trials", "1 continuous lap": the count and the noun in the number it needs."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def trials_text(trials: int, continuous: bool) -> str:
    """How many laps a race drives and how: "1 continuous lap", "3 continuous laps", "3 trials"."""
    return counted(trials, "continuous lap" if continuous else "trial")


def result_text(laps: list[Lap]) -> str:
    """The result in the league's words: "no lap completed", "one lap: T s", "N laps, average T s"."""
    done = [lap for lap in laps if lap.completed]
    if not done:
        return "no lap completed"
    if len(done) == 1:
        return f"one lap: {done[0].time:.3f} s"
    mean = math.floor(sum(lap.time_ms for lap in done) / len(done)) / 1000
    return f"{len(done)} laps, average {mean:.3f} s"


@dataclass(frozen=True)
class RaceResult:
    """What a race ranks by, computed from the laps of one evaluation."""

    laps: int  # trials driven
    laps_completed: int
    completed_streak: int
    best_lap: float | None  # s
    mean_lap: float | None  # s, over the completed laps
    ranking_laps: int
    ranking_average: float | None  # s, best mean over `ranking_laps` consecutive completed laps
    total_time: float  # s, every lap's elapsed time (penalties included)
    off_track: int
    resets: int
    mean_progress: float  # %, over all laps
    text: str
    crashes: int = 0  # crashes into boxes, bot cars or the other racer

    def to_json(self) -> dict:
        return dict(self.__dict__)


def race_result(laps: list[Lap], ranking_laps: int = DEFAULT_RANKING_LAPS) -> RaceResult:
    window = max(1, min(ranking_laps, len(laps)))
    done = [lap for lap in laps if lap.completed]
    return RaceResult(
        laps=len(laps), laps_completed=len(done), completed_streak=completed_streak(laps),
        best_lap=min(lap.time for lap in done) if done else None,
        mean_lap=math.floor(sum(lap.time_ms for lap in done) / len(done)) / 1000 if done else None,
        ranking_laps=window, ranking_average=best_consecutive_average(laps, window),
        total_time=sum(lap.time_ms for lap in laps) / 1000,
        off_track=sum(lap.counts["off_track"] for lap in laps), resets=sum(lap.resets for lap in laps),
        mean_progress=sum(min(lap.progress, 100.0) for lap in laps) / len(laps) if laps else 0.0,
        text=result_text(laps), crashes=sum(lap.counts["crashed"] for lap in laps))


def rank_key(r: RaceResult) -> tuple:
    """Sort key of a leaderboard: a full ranking average first (smaller is better), then more
    completed laps, then the best lap, then progress."""
    inf = math.inf
    return (r.ranking_average is None, r.ranking_average if r.ranking_average is not None else inf,
            -r.laps_completed, r.best_lap if r.best_lap is not None else inf, -r.mean_progress)


# ---- text --------------------------------------------------------------------------------------


def _seconds(x: float | None) -> str:
    return "-" if x is None else f"{x:.3f} s"


def lap_table(laps: list[Lap]) -> str:
    """Each lap's time, how it ended, progress, off-tracks, crashes and resets, as aligned text."""
    head = (f"{'lap':>4}  {'time (s)':>9}  {'status':<13}  {'progress':>9}  {'off-track':>9}  {'crashes':>7}  "
            f"{'resets':>6}")
    lines = [head]
    for lap in laps:
        label = STATUS_LABELS.get(lap.status, lap.status).lower()
        lines.append(f"{lap.trial:>4}  {lap.time:>9.3f}  {label:<13}  {lap.progress:>8.1f}%  "
                     f"{lap.counts['off_track']:>9}  {lap.counts['crashed']:>7}  {lap.resets:>6}")
    return "\n".join(lines)


def result_lines(r: RaceResult) -> list[str]:
    avg = (f"best {r.ranking_laps}-lap average {_seconds(r.ranking_average)}" if r.ranking_laps > 1
           else "")
    parts = [f"best lap {_seconds(r.best_lap)}", avg,
             f"{r.completed_streak} completed in a row" if r.laps_completed else "",
             f"{r.off_track} off-track", f"{r.crashes} crashes" if r.crashes else "", f"total {r.total_time:.3f} s"]
    return [" | ".join(p for p in parts if p), f"result: {r.text}"]
