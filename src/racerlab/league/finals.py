"""Head-to-model finals: the top racers of a race drive their ranked models together on the race's track.

`League.start_final(actor, race)` (staff) freezes the entrants (the two best rows of the race's leaderboard, their
ranked submissions' models) and runs the final in a fresh process with the workers' pinned environment
(`evaluation.PIN_ENV`): `run_final` opens the stored models (safetensors only), loads the race's pinned track and
drives them with `racerlab.evaluate.race.head_to_model_loaded` (the simulator's head-to-model race: one world, a
car each, each seeing and able to hit the other) under the race's frozen rules (laps, penalties, resets, time cap,
direction, car, seed), one torch thread. Nothing in it reads the clock or an unseeded random source, so the same
models give the same final, lap for lap. The race's boxes or bot cars are not on the track: the simulator's
head-to-model race holds the racing cars alone. Two cars: the simulator races cars in pairs.

The order (`final_order`): more completed laps first; among cars that completed every lap, the smaller total time
(penalties inside); among the others, the farther progress into the lap they were on when the race ended for
them; then the better qualifying rank. Each car's evaluation (simtrace, EvalMetrics.json, summary.json and the
video when the race records one) is kept in results/final-<id>/car-<place in qualifying>/.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import threading
from datetime import timedelta
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from racerlab.errors import RacerlabError
from racerlab.league import audit
from racerlab.league.people import Actor, may, require_role
from racerlab.league.store import LeagueError, Store
from racerlab.league.tables import Final, Race, utcnow
from racerlab.league.views import FinalView, loads

FINAL_SIZE = 2  # the simulator's head-to-model race pairs cars
LOST_AFTER = timedelta(minutes=30)  # a final's process runs a few minutes at most (two cars, the race's time cap)
FINAL_FILES = {"simtrace": "evaluation-simtrace/0-iteration.csv", "metrics": "EvalMetrics.json",
               "summary": "summary.json", "video": "evaluation.mp4"}


def final_order(cars: list[dict], laps: int) -> list[dict]:
    """`cars` (each with "laps": `evaluate.Lap`s and "qualifying_rank") in the final's order, with their figures."""
    rows = sorted((_figures(car, laps) for car in cars), key=_place_key)
    for place, r in enumerate(rows, 1):
        r["place"] = place
    return rows


def _figures(car: dict, laps: int) -> dict:
    driven = car["laps"]
    done = sum(1 for lap in driven if lap.completed)
    finished = done >= laps
    last = driven[-1] if driven else None
    progress = 0.0 if finished or last is None or last.completed else float(last.progress)
    total_ms = sum(lap.time_ms for lap in driven)
    return {**{k: v for k, v in car.items() if k != "laps"}, "finished": finished, "laps_completed": done,
            "total_s": total_ms / 1000 if finished else None, "progress": round(progress, 4),
            "off_track": sum(lap.counts.get("off_track", 0) for lap in driven),
            "crashed": sum(lap.counts.get("crashed", 0) for lap in driven), "laps": [lap.to_json() for lap in driven]}


def _place_key(r: dict) -> tuple:
    """More completed laps; a finisher's smaller total time; the farther progress; the better qualifying rank."""
    total_ms = round(r["total_s"] * 1000) if r["finished"] else 0
    return (-r["laps_completed"], total_ms, -round(r["progress"] * 1000), r["qualifying_rank"])


def run_final(store: Store, final_id: int) -> str:
    """Race final `final_id` and store its result (status done) or why it could not run (failed); the status."""
    with store.read() as s:
        final = s.get(Final, final_id)
        race = s.get(Race, final.race_id)
        entrants, rules_json, rules_hash = loads(final.entrants_json), race.rules_json, final.rules_hash
    try:
        result = _race(store, final_id, entrants, rules_json, rules_hash)
    except RacerlabError as exc:
        return _finish(store, final_id, "failed", _line(str(exc), store), None)
    except Exception as exc:  # noqa: BLE001 - any failure is stored as one line
        return _finish(store, final_id, "failed", f"the final failed ({type(exc).__name__}: "
                       f"{_line(str(exc), store)})", None)
    return _finish(store, final_id, "done", "", result)


def _race(store: Store, final_id: int, entrants: list[dict], rules_json: str, rules_hash: str) -> dict:
    import torch

    from racerlab import __version__
    from racerlab.evaluate.race import head_to_model_loaded
    from racerlab.league.evaluation import VIDEO_EVERY, VIDEO_WIDTH_PX, open_stored
    from racerlab.league.rules import Rules, load_pinned

    rules = Rules.from_json(rules_json)
    if rules.hash != rules_hash:
        raise LeagueError("the race's stored rules do not match the final's rules hash; the store was changed")
    torch.set_num_threads(1)
    torch.manual_seed(rules.seed)
    track = load_pinned(store.folder / "tracks", *rules.driven_track)
    models = [open_stored(store.model_dir(e["model_hash"])) for e in entrants]
    folder = store.folder / "results" / f"final-{final_id}"
    title = f"final: {' vs '.join(e['alias'] for e in entrants)} on {track.name}"
    results = head_to_model_loaded(models, track, rules.race_rules(), ranking_laps=max(1, rules.min_laps),
                                   video=rules.video, car=rules.car, seed=rules.seed,
                                   out_dirs=[folder / f"car-{k + 1}" for k in range(len(models))],
                                   look=(VIDEO_WIDTH_PX, title, VIDEO_EVERY))
    cars = [{**e, "car": k + 1, "laps": r.laps} for k, (e, r) in enumerate(zip(entrants, results, strict=True))]
    return {"order": final_order(cars, rules.laps), "rules_hash": rules.hash, "seed": rules.seed,
            "laps": rules.laps, "racerlab_version": __version__, "steps": [r.steps for r in results],
            "result_dir": str(folder.relative_to(store.folder))}


def _line(text: str, store: Store) -> str:
    first = (text.strip().splitlines() or [""])[0]
    return first.replace(str(store.folder), "the league folder")[:480]


def _finish(store: Store, final_id: int, status: str, reason: str, result: dict | None) -> str:
    with store.write() as s:
        final = s.get(Final, final_id)
        if final.status != "running":
            return final.status
        final.status, final.reason, final.finished_at = status, reason, utcnow()
        if result is not None:
            final.result_dir = result.pop("result_dir")
            final.result_json = json.dumps(result, sort_keys=True)
        race = s.get(Race, final.race_id)
        race.version += 1
        audit.record(s, None, "final.result", f"final:{final_id}", race=race.name, status=status,
                     order=[r["alias"] for r in (result or {}).get("order", [])], reason=reason)
    return status


def _child(folder: str, url: str, final_id: int) -> None:
    """A final's process: the workers' environment before torch loads, then the race."""
    from racerlab.league.evaluation import pin_environment

    pin_environment()
    store = Store(folder, url)
    try:
        run_final(store, final_id)
    finally:
        store.dispose()


def launch(store: Store, final_id: int, wait: bool = True) -> None:
    """Run final `final_id` in a fresh process (spawned, so the pinned environment is set before torch loads):
    waited for, or watched from a thread. A process that dies without a result leaves the final failed."""
    proc = mp.get_context("spawn").Process(target=_child, args=(str(store.folder), store.url, final_id),
                                           name=f"league-final-{final_id}")
    proc.start()

    def watch() -> None:
        proc.join()
        if proc.exitcode != 0:
            _finish(store, final_id, "failed", f"the final's process ended without a result (exit code "
                    f"{proc.exitcode}); start the final again", None)

    if wait:
        watch()
    else:
        threading.Thread(target=watch, daemon=True, name=f"league-final-{final_id}").start()


class FinalsMixin:
    """`League`'s final calls (see `racerlab.league.service.League`)."""

    def start_final(self, actor: Actor, race: str, size: int = FINAL_SIZE, wait: bool = True) -> FinalView:
        """Staff start a head-to-model final of `race` between its top `size` (2) racers; `wait` for its result,
        or return at once with the final running (a web page)."""
        require_role(actor, "final.start")
        if size != FINAL_SIZE:
            raise LeagueError(f"a final races {FINAL_SIZE} models head to head (the simulator's head-to-model race "
                              f"pairs cars), not {size}")
        with self.store.write() as s:
            self._acting(s, actor, "final.start")
            row = self._race_row(s, race)
            self._running_final(s, row)
            entrants = self._top(s, row, size)
            final = Final(race_id=row.id, status="running", reason="", entrants_json=json.dumps(entrants),
                          rules_hash=row.rules_hash, created_by=actor.id)
            s.add(final)
            row.version += 1
            s.flush()
            audit.record(s, actor, "final.start", f"final:{final.id}", race=row.name,
                         entrants=[e["alias"] for e in entrants])
            final_id = final.id
        launch(self.store, final_id, wait)
        return self.final(actor, final_id)

    def _running_final(self, s: Session, race: Race) -> None:
        """Refuse a second final while one runs; one running longer than `LOST_AFTER` lost its process (a server
        stopped under it) and is failed, so that it does not hold the race's finals for ever."""
        running = s.scalars(select(Final).where(Final.race_id == race.id, Final.status == "running")).first()
        if running is None:
            return
        if utcnow() - running.created_at < LOST_AFTER:
            raise LeagueError(f"race {race.name!r} has a final running; wait for its result", 409)
        running.status, running.finished_at = "failed", utcnow()
        running.reason = "its process ended without a result (the server stopped?); started again"
        audit.record(s, None, "final.result", f"final:{running.id}", race=race.name, status="failed",
                     reason=running.reason)

    def _top(self, s: Session, race: Race, size: int) -> list[dict]:
        from racerlab.league.submissions import race_rows

        ranked = [r for r in race_rows(s, race) if r.rank is not None][:size]
        if len(ranked) < size:
            raise LeagueError(f"race {race.name!r} has {len(ranked)} ranked racer(s); a final needs {size}", 409)
        return [{"alias": r.alias, "qualifying_rank": r.rank, "submission_id": r.submission_id,
                 "model_hash": r.model_hash} for r in ranked]

    def final(self, actor: Actor, final_id: int) -> FinalView:
        """A final, its entrants and (when done) its order; seen by everyone who sees the race's leaderboard."""
        with self.store.read() as s:
            self._acting(s, actor, "standings.view")
            final = s.get(Final, int(final_id))
            if final is None:
                raise LeagueError(f"no final {final_id}", 404)
            return self._final_view(s, final, actor)

    def finals(self, actor: Actor, race: str) -> list[FinalView]:
        """A race's finals, the newest first."""
        with self.store.read() as s:
            self._acting(s, actor, "standings.view")
            row = self._race_row(s, race)
            return [self._final_view(s, f, actor) for f in
                    s.scalars(select(Final).where(Final.race_id == row.id).order_by(Final.id.desc()))]

    def _final_view(self, s: Session, final: Final, actor: Actor) -> FinalView:
        race = s.get(Race, final.race_id)
        result = loads(final.result_json, {})
        view = FinalView(final.id, race.name, final.status, final.reason, final.rules_hash,
                         loads(final.entrants_json, []), result.get("order", []), final.created_at, final.finished_at)
        for car in view.order:
            view.files[car["place"]] = [k for k in FINAL_FILES if self._final_path(final, race, car, k, actor)]
        return view

    def _final_path(self, final: Final, race: Race, car: dict, kind: str, actor: Actor) -> Path | None:
        """A car's file when it exists and the actor may have it (their own car, staff, or a public video)."""
        own = car["alias"] == actor.alias or may(actor.role, "submission.view_any")
        if not final.result_dir or not (own or (kind == "video" and race.public_videos)):
            return None
        path = self.store.path(final.result_dir) / f"car-{car['car']}" / FINAL_FILES[kind]
        return path if path.is_file() else None

    def final_file(self, actor: Actor, final_id: int, place: int, kind: str) -> Path:
        """The `kind` file (`FINAL_FILES`) of the car in `place` of a done final."""
        if kind not in FINAL_FILES:
            raise LeagueError(f"file {kind!r}: one of {', '.join(FINAL_FILES)}", 404)
        with self.store.read() as s:
            self._acting(s, actor, "standings.view")
            final = s.get(Final, int(final_id))
            race = s.get(Race, final.race_id) if final is not None else None
            car = next((c for c in loads(final.result_json, {}).get("order", []) if c["place"] == int(place)),
                       None) if final is not None else None
            path = self._final_path(final, race, car, kind, actor) if car is not None else None
        if path is None:
            raise LeagueError(f"final {final_id} has no {kind} for place {place} that you may see", 404)
        return path
