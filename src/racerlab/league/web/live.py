"""A race's live board as server-sent events, and what the many browsers of one race share in this process.

On race day a hundred racers keep the race's page open and scripts poll its standings; asking the database for
each of them would cost a core. `Boards` shares the work:

- the race's version (`League.race_version`: it changes with every status and result of the race) is read at most
  every `POLL_S` per race, whoever asks;
- the standings are computed once per version and handed to every asker (they are the same for everyone);
- a racer's own submissions in the race are read again when the version moved and they had one under way or their
  leaderboard row changed, and at least every `MINE_TTL_S` (queue places and ETAs move with other races' work).

Each asker's role is checked before anything is handed out (`people.require_role`), and the account itself is
looked up in the service at least every `REFRESH_S` on a stream, so a disabled account's stream ends within it (an
`error` event says why). `board_events` sends a `board` event when the version moved (at most one every
`MIN_GAP_S`) and every `REFRESH_S` anyway (the event doubles as a keep-alive). Nothing runs for a browser that is
not connected.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections import OrderedDict

from starlette.concurrency import run_in_threadpool

from racerlab.league import people
from racerlab.league.people import Actor
from racerlab.league.store import LeagueError
from racerlab.league.views import FINAL

POLL_S = 0.5
MIN_GAP_S = 1.0
REFRESH_S = 10.0
MINE_TTL_S = 5.0
MAX_MINE = 4096  # racers' lists kept (each a few kB)
MINE_KEYS = ("id", "number", "model_name", "model_hash", "checkpoint", "created_at", "status", "status_text",
             "reason", "position", "eta_s", "score_ms", "laps_completed", "laps_driven", "off_track", "note")


def sse(event: str, data) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'), allow_nan=False)}\n\n"


class Boards:
    """The shared reads of the races' live pages and polls in this server process (see the module's docstring)."""

    def __init__(self, league, poll_s: float = POLL_S, mine_ttl_s: float = MINE_TTL_S):
        self.league, self.poll_s, self.mine_ttl_s = league, poll_s, mine_ttl_s
        self._lock = threading.Lock()
        self._versions: dict[str, tuple[int, float]] = {}
        self._standings: dict[str, dict] = {}
        self._meta: dict[str, tuple[int, dict]] = {}
        self._mine: OrderedDict[tuple[int, str], tuple[int, float, list]] = OrderedDict()

    def version(self, actor: Actor, race: str) -> int:
        people.require_role(actor, "race.view")
        now = time.monotonic()
        with self._lock:
            hit = self._versions.get(race)
        if hit is not None and now - hit[1] < self.poll_s:
            return hit[0]
        version = self.league.race_version(actor, race)  # 404 for a race that is not there
        with self._lock:
            self._versions[race] = (version, now)
        return version

    def standings(self, actor: Actor, race: str) -> dict:
        """The race's standings as JSON (`Standings.to_json()`), computed once per version."""
        version = self.version(actor, race)
        people.require_role(actor, "standings.view")
        with self._lock:
            hit = self._standings.get(race)
        if hit is not None and hit["version"] >= version:
            return hit
        fresh = self.league.standings(actor, race).to_json()
        with self._lock:
            held = self._standings.get(race)
            if held is None or held["version"] <= fresh["version"]:
                self._standings[race] = fresh
        return fresh

    def meta(self, actor: Actor, race: str) -> dict:
        """What every racer's page shows of the race itself: its state and submission limit (per version)."""
        version = self.version(actor, race)
        with self._lock:
            hit = self._meta.get(race)
        if hit is not None and hit[0] >= version:
            return hit[1]
        view = self.league.race(actor, race)
        out = {"name": view.name, "state": view.state, "max_submissions": view.max_submissions}
        with self._lock:
            self._meta[race] = (view.version, out)
        return out

    def mine(self, actor: Actor, race: str, force: bool = False) -> list[dict]:
        """The actor's own submissions in the race as JSON (newest first), read again when the version moved or
        after `mine_ttl_s`."""
        version, now, key = self.version(actor, race), time.monotonic(), (actor.id, race)
        with self._lock:
            hit = self._mine.get(key)
        if not force and hit is not None and hit[0] == version and now - hit[1] < self.mine_ttl_s:
            return hit[2]
        subs = [s.to_json() for s in self.league.submissions(actor, race)]
        with self._lock:
            self._mine[key] = (version, now, subs)
            self._mine.move_to_end(key)
            while len(self._mine) > MAX_MINE:
                self._mine.popitem(last=False)
        return subs


def _row(standings: dict, alias: str) -> dict | None:
    return next((r for r in standings["rows"] if r["alias"] == alias), None)


def board(boards: Boards, actor: Actor, race: str, previous: dict | None = None, check: bool = False) -> dict:
    """What a race page shows live: the race, its standings, the caller's own submissions in it. `previous` is the
    board sent last (the own list is read again only when it had one under way or the caller's row changed);
    `check` looks the account up in the service first."""
    if check:
        boards.league.race_version(actor, race)  # a disabled or changed account: LeagueError, the stream ends
    standings = boards.standings(actor, race)
    row = _row(standings, actor.alias)
    if previous is not None and not check and row == _row(previous["standings"], actor.alias) and all(
            s["status"] in FINAL for s in previous["mine"]):
        mine = previous["mine"]  # nothing of theirs under way and their row as it was: their list is too
    else:
        mine = [{k: v for k, v in s.items() if k in MINE_KEYS}
                for s in boards.mine(actor, race, force=previous is not None)]
    meta = boards.meta(actor, race)
    used = row["submissions"] if row else 0
    return {"race": {**meta, "version": standings["version"], "submissions_used": used},
            "standings": standings, "mine": mine}


async def board_events(request, actor: Actor, race: str, poll_s: float = POLL_S, refresh_s: float = REFRESH_S,
                       gap_s: float = MIN_GAP_S):
    boards: Boards = request.app.state.boards
    last, sent = None, 0.0
    while not await request.is_disconnected():
        try:
            version = await run_in_threadpool(boards.version, actor, race)
            now = time.monotonic()
            due = now - sent >= refresh_s
            if due or (last is not None and version != last["race"]["version"] and now - sent >= gap_s):
                last = await run_in_threadpool(board, boards, actor, race, last, due and last is not None)
                sent = time.monotonic()
                yield sse("board", last)
        except LeagueError as exc:
            yield sse("error", {"error": str(exc), "status": exc.status})
            return
        await asyncio.sleep(poll_s)
