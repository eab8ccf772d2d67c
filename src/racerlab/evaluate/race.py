"""`race(models)`: several models evaluated on one track under the same rules, and the leaderboard.

Each model gets its own evaluation folder (as `evaluate` writes it); the leaderboard ranks them
by `results.rank_key`: the best average over `ranking_laps` consecutive completed laps, as
DeepRacer on AWS ranks, then more completed laps, the best lap and progress for the rest.

A race can be stopped (`cancel`, set from another thread: the console's Cancel button) at the end of any lap:
the models already done keep their evaluation folders, the one on the track writes none, and no leaderboard is
written (`RaceCancelled` says which were done). A head-to-model race stops the same way; its two cars drive
together, so neither keeps an evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from racerlab import logs
from racerlab.errors import RacerlabError
from racerlab.evaluate.api import RACE_SEED, EvaluationResult, _write, evaluate, run_pair
from racerlab.evaluate.results import DEFAULT_RANKING_LAPS, race_result, rank_key
from racerlab.evaluate.rules import RaceRules
from racerlab.logs.layout import STAMP_FORMAT
from racerlab.model import ModelFolder, resolve_track


class RaceCancelled(RacerlabError):
    """A race stopped on request before its last model; `done` are the finished models' results."""

    def __init__(self, done: list[EvaluationResult], total: int):
        self.done = done
        super().__init__(stopped_text("cancelled", [r.model for r in done], total))


def stopped_text(how: str, finished: list[str], total: int) -> str:
    """What a race stopped early leaves: the finished models' evaluations, no leaderboard."""
    if not finished:
        return f"race {how} after 0 of {total} models: nothing was written"
    return (f"race {how} after {len(finished)} of {total} models: the evaluations of {', '.join(finished)} are kept "
            "in their model folders; no leaderboard was written")


@dataclass
class Leaderboard:
    track: str
    rules: RaceRules
    ranking_laps: int
    entries: list[EvaluationResult]  # best first
    path: Path | None = None

    def rows(self) -> list[dict]:
        out = []
        for rank, e in enumerate(self.entries, 1):
            r = e.result
            out.append({"rank": rank, "model": e.model, "model_dir": str(e.model_dir), "checkpoint": e.checkpoint,
                        "result": r.text, "best_lap": r.best_lap, "ranking_average": r.ranking_average,
                        "mean_lap": r.mean_lap, "laps_completed": r.laps_completed, "laps": r.laps,
                        "completed_streak": r.completed_streak, "off_track": r.off_track, "crashes": r.crashes,
                        "resets": r.resets,
                        "total_time": r.total_time, "mean_progress": round(r.mean_progress, 2),
                        "evaluation": str(e.out_dir) if e.out_dir else None})
        return out

    def to_json(self) -> dict:
        return {"track": self.track, "rules": self.rules.to_json(), "ranking_laps": self.ranking_laps,
                "created": datetime.now().isoformat(timespec="seconds"), "leaderboard": self.rows()}

    def table(self) -> str:
        def sec(x):
            return "-" if x is None else f"{x:.3f}"

        width = max([5, *(len(e.model) for e in self.entries)])
        avg = f"avg {self.ranking_laps}"
        lines = [f"{'rank':>4}  {'model':<{width}}  {'best lap':>8}  {avg:>8}  {'laps':>5}  {'off-track':>9}  "
                 f"{'crashes':>7}  {'resets':>6}  result"]
        for row in self.rows():
            laps = f"{row['laps_completed']}/{row['laps']}"
            lines.append(f"{row['rank']:>4}  {row['model']:<{width}}  {sec(row['best_lap']):>8}  "
                         f"{sec(row['ranking_average']):>8}  {laps:>5}  {row['off_track']:>9}  {row['crashes']:>7}  "
                         f"{row['resets']:>6}  {row['result']}")
        return "\n".join(lines)


def race(model_dirs, track=None, *, rules: RaceRules | None = None, checkpoint: str | int = "best",
         ranking_laps: int = DEFAULT_RANKING_LAPS, out=None, video: bool = False, progress: bool = False,
         on_result=None, device: str = "cpu", race=None, car=None, cancel=None) -> Leaderboard:
    """Evaluate every model on `track` (default: the first model's training track) under `rules` and
    rank them; the leaderboard is written as JSON to `out` (default `race-<stamp>.json` in the first model's
    folder, never the current directory; `out=False` writes nothing). No model's reward_function.py is run.
    `on_result(result)` is called after each model. `race` is passed to each `evaluate` (a RaceConfig, or
    [race] keys over each model's own); `car` likewise (a simulator name, a [car] dict or a `CarParams`; default
    each model's own [car]). `cancel` (a `threading.Event`) stops the race at the next lap's end with
    `RaceCancelled`."""
    model_dirs = [Path(m) for m in model_dirs]
    if not model_dirs:
        raise RacerlabError("race needs at least one model folder")
    rules = rules or RaceRules()
    if track is None:
        track = resolve_track(model_dirs[0])
    results = []

    def lap_end(lap) -> None:
        if cancel is not None and cancel.is_set():
            raise RaceCancelled(results, len(model_dirs))

    for m in model_dirs:
        lap_end(None)
        res = evaluate(m, track=track, rules=rules, checkpoint=checkpoint, ranking_laps=ranking_laps, video=video,
                       progress=progress, device=device, race=race, car=car, on_lap=lap_end)
        results.append(res)
        if on_result:
            on_result(res)
    return _board(results, rules, out, model_dirs[0])


def head_to_model(model_a, model_b, track=None, *, rules: RaceRules | None = None, checkpoint: str | int = "best",
                  ranking_laps: int = DEFAULT_RANKING_LAPS, out=None, video: bool = False, progress: bool = False,
                  on_result=None, on_lap=None, device: str = "cpu", write: bool = True, car=None,
                  cancel=None) -> Leaderboard:
    """Two models on the track at once (`racerlab race A B --head-to-model`): one world, a car each, each car's
    sensors and `objects_*` params seeing the other car, crashes between them judged by the crash rule (the car
    behind crashed). Each model's evaluation folder gets its simtrace, EvalMetrics and summary (and video); the
    leaderboard ranks the two as `race` does. `on_lap(k, lap)` is called as car k ends a lap. `cancel` (a
    `threading.Event`) stops the race at the next lap's end with `RaceCancelled`: the two drive together, so
    neither writes an evaluation."""
    rules = rules or RaceRules()
    dirs = [Path(model_a), Path(model_b)]

    def lap_end(k, lap) -> None:
        if cancel is not None and cancel.is_set():
            raise RaceCancelled([], 2)
        if on_lap is not None:
            on_lap(k, lap)

    models = [ModelFolder(m).open(checkpoint) for m in dirs]
    track_obj = resolve_track(models[0].folder, track)
    results = head_to_model_loaded(models, track_obj, rules, ranking_laps=ranking_laps, video=video,
                                   progress=progress, on_result=on_result, on_lap=lap_end, device=device,
                                   write=write, car=car)
    return _board(results, rules, out, dirs[0])


def head_to_model_loaded(models, track, rules: RaceRules, *, ranking_laps: int = DEFAULT_RANKING_LAPS,
                         video: bool = False, progress: bool = False, on_result=None, on_lap=None,
                         device: str = "cpu", write: bool = True, car=None, seed: int = RACE_SEED,
                         out_dirs=None, look: tuple | None = None) -> list[EvaluationResult]:
    """`head_to_model` of two models already open (`ModelFolder.open`, or a race server's stored models) on a
    `Track`: each car's `EvaluationResult`, in the order given. `seed` seeds the world; `out_dirs` (one per car)
    receive the evaluations' files instead of new evaluation folders in the model folders; `look` is the video's
    (track width in pixels, title or None, every k-th step)."""
    worlds, runs = run_pair(models, track, rules, video=video, on_lap=on_lap, device=device,
                            where="racerlab race --head-to-model", car=car, seed=seed)
    results = []
    for k, (m, w, run) in enumerate(zip(models, worlds, runs, strict=True)):
        res = EvaluationResult(m.name, m.folder.path, m.checkpoint.name, track.name, rules,
                               run.laps, race_result(run.laps, ranking_laps), steps=run.rows,
                               wall_seconds=run.wall_seconds, run=run, race={"type": "head_to_model"},
                               car=w.sim.car_params.name)
        if write:
            _write(res, w, video, progress, out_dirs[k] if out_dirs else None, *([look] if look else []))
        results.append(res)
        if on_result:
            on_result(res)
    return results


def _board(results: list[EvaluationResult], rules: RaceRules, out, home: Path) -> Leaderboard:
    """Rank `results`; the JSON goes to `out`, or `race-<stamp>.json` in `home` (the first model's folder)."""
    _disambiguate(results)
    board = Leaderboard(results[0].track, rules, results[0].result.ranking_laps,
                        sorted(results, key=lambda r: rank_key(r.result)))
    if out is not False:
        path = Path(out) if out else home / f"race-{datetime.now().strftime(STAMP_FORMAT)}.json"
        board.path = logs.atomic_write_json(path, logs.finite_json(board.to_json()), indent=2)
    return board


def _disambiguate(results: list[EvaluationResult]) -> None:
    """Two folders with the same name are told apart by their paths."""
    names = [r.model for r in results]
    for r in results:
        if names.count(r.model) > 1:
            r.model = str(r.model_dir)

