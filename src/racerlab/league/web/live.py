"""A race's live board as server-sent events, and what the many browsers of one race share in this process.

On race day a hundred racers keep the race's page open and scripts poll its standings; asking the database for
each of them would cost a core. `Boards` shares the work:

- the race's version (`League.race_version`: it changes with every status and result of the race) is read at most
  every `POLL_S` per race, whoever asks, and at once after a submission, requeue or race change made through this
  server (`touch`);
- the standings and the race's limits are read once per version and handed to every asker (they are the same for
  everyone); the race's state (upcoming, open, closed) is worked out from its times at each hand-out, since it
  moves with the clock, not the version;
- a racer's own submissions in the race are read again when their row on the leaderboard changed, after a change
  of theirs (or of staff) made through this server, and at least every `MINE_TTL_S` (a status that does not show
  in the row, queue places and ETAs): reading them at every move of the race would cost a hundred reads a second
  on race day.

Who asks is checked before anything is handed out: the route's token (`auth.TokenCache`) and the role
(`people.require_role`). A stream asks again at every look (`auth.recheck`), so logging out, a revoked token or a
disabled account ends it within `POLL_S` when done through this server, within the token TTL when done elsewhere
(an `error` event says why). `board_events` sends a `board` event when the version moved (at most one every
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
from racerlab.league.races import race_state
from racerlab.league.store import LeagueError
from racerlab.league.tables import utcnow
from racerlab.league.web.auth import recheck

POLL_S = 0.5
MIN_GAP_S = 1.0
REFRESH_S = 10.0
MINE_TTL_S = 5.0
MAX_MINE = 4096  # racers' lists kept (each a few kB)
MINE_KEYS = ("id", "number", "model_name", "model_hash", "checkpoint", "created_at", "status", "status_text",
             "reason", "position", "eta_s", "score_ms", "laps_completed", "laps_driven", "off_track", "note")


def encode(body) -> bytes:
    """JSON as the API's responses send it (Starlette's JSONResponse: compact, UTF-8, no NaN)."""
    return json.dumps(body, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode("utf-8")


def sse(event: str, data) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'), allow_nan=False)}\n\n"


class Boards:
    """The shared reads of the races' live pages and polls in this server process (see the module's docstring)."""

    def __init__(self, league, poll_s: float = POLL_S, mine_ttl_s: float = MINE_TTL_S):
        self.league, self.poll_s, self.mine_ttl_s = league, poll_s, mine_ttl_s
        self._lock = threading.Lock()
        self._versions: dict[str, tuple[int, float]] = {}
        self._standings: dict[str, dict] = {}
        self._races: dict[str, tuple[int, dict]] = {}
        self._encoded: dict[str, tuple[tuple, bytes]] = {}
        self._readers: dict[tuple[str, str], threading.Lock] = {}
        self._mine: OrderedDict[tuple[int, str], tuple[dict | None, float, list]] = OrderedDict()

    def touch(self, actor: Actor | None = None) -> None:
        """A change made through this server by `actor`: the next look at any race asks the store for its version
        (and so reads its standings again when they moved); the actor's own lists are read again (a member of staff:
        everyone's, since staff change others' submissions). A stranger's request (a login, a sign-up) changes
        nothing a board shows, so the racers' lists stay: dropping them all at each of a crowd's logins and uploads
        sent every poll to the store at once."""
        with self._lock:
            self._versions.clear()
            if actor is None:
                return
            if actor.staff:
                self._mine.clear()
                return
            for key in [k for k in self._mine if k[0] == actor.id]:
                del self._mine[key]

    def _through(self, kind: str, race: str, table: dict, current, read):
        """`table[race]` when `current(it)`, else read again by one thread (`read()`) while the others wait for its
        answer: a crowd's polls that miss together would otherwise each read the same rows."""
        with self._lock:
            hit = table.get(race)
        if current(hit):
            return hit
        with self._lock:
            reader = self._readers.setdefault((kind, race), threading.Lock())
        with reader:
            with self._lock:
                hit = table.get(race)
            if not current(hit):
                hit = read()
                with self._lock:
                    table[race] = hit
        return hit

    def _version_current(self, hit) -> bool:
        return hit is not None and time.monotonic() - hit[1] < self.poll_s

    def _held_version(self, race: str) -> int | None:
        with self._lock:
            hit = self._versions.get(race)
        return hit[0] if self._version_current(hit) else None

    def version(self, actor: Actor, race: str) -> int:
        people.require_role(actor, "race.view")

        def read() -> tuple[int, float]:
            at = time.monotonic()
            return self.league.race_version(actor, race), at  # 404 for a race that is not there

        return self._through("version", race, self._versions, self._version_current, read)[0]

    def standings(self, actor: Actor, race: str) -> dict:
        """The race's standings as JSON (`Standings.to_json()`), read once per version."""
        version = self.version(actor, race)
        people.require_role(actor, "standings.view")
        hit = self._through("standings", race, self._standings, lambda h: h is not None and h["version"] >= version,
                            lambda: self.league.standings(actor, race).to_json())
        return {**hit, "state": self.meta(actor, race)["state"]}

    # ---- from memory alone, on the event loop: None when only the store can say ------------------------------
    def _fresh(self, actor: Actor, race: str) -> tuple[dict, dict] | None:
        """(standings, race meta) held for the race's version, read within `poll_s`; the actor's roles checked."""
        people.require_role(actor, "race.view")
        people.require_role(actor, "standings.view")
        version = self._held_version(race)
        with self._lock:
            standings, meta = self._standings.get(race), self._races.get(race)
        if version is None or standings is None or meta is None or min(standings["version"], meta[0]) < version:
            return None
        return standings, meta[1]

    def standings_json_held(self, actor: Actor, race: str) -> bytes | None:
        """`standings_json` when it needs no read of the store; None otherwise (then call `standings_json`)."""
        fresh = self._fresh(actor, race)
        if fresh is None:
            return None
        standings, meta = fresh
        state = race_state(meta["opens_at"], meta["closes_at"], utcnow())
        with self._lock:
            hit = self._encoded.get(race)
        return hit[1] if hit is not None and hit[0] == (standings["version"], state) else None

    def mine_held(self, actor: Actor, race: str) -> list[dict] | None:
        """`mine` when it needs no read of the store; None otherwise (then call `mine`)."""
        fresh = self._fresh(actor, race)
        if fresh is None:
            return None
        row, now = own_row(fresh[0], actor.alias), time.monotonic()
        with self._lock:
            hit = self._mine.get((actor.id, race))
        return hit[2] if hit is not None and hit[0] == row and now - hit[1] < self.mine_ttl_s else None

    def version_held(self, actor: Actor, race: str) -> int | None:
        people.require_role(actor, "race.view")
        return self._held_version(race)

    # ---- through the store when needed (in a thread) -----------------------------------------------------------
    def standings_json(self, actor: Actor, race: str) -> bytes:
        """`standings` as the JSON a response sends, encoded once per version and state (a hundred rows took
        ~30 ms through FastAPI's generic encoder on every poll: the crowd's polls were the server's CPU)."""
        body = self.standings(actor, race)
        key = (body["version"], body["state"])
        with self._lock:
            hit = self._encoded.get(race)
        if hit is None or hit[0] != key:
            hit = (key, encode(body))
            with self._lock:
                self._encoded[race] = hit
        return hit[1]

    def meta(self, actor: Actor, race: str) -> dict:
        """What every racer's page shows of the race itself: its state (now) and submission limit."""
        version = self.version(actor, race)

        def read() -> tuple[int, dict]:
            view = self.league.race(actor, race)
            return view.version, {"name": view.name, "max_submissions": view.max_submissions,
                                  "opens_at": view.opens_at, "closes_at": view.closes_at}

        held = self._through("race", race, self._races, lambda h: h is not None and h[0] >= version, read)[1]
        return {"name": held["name"], "state": race_state(held["opens_at"], held["closes_at"], utcnow()),
                "max_submissions": held["max_submissions"]}

    def mine(self, actor: Actor, race: str) -> list[dict]:
        """The actor's own submissions in the race as JSON (newest first): read again when their leaderboard row
        changed, after a change made through this server (`touch`), and at least every `mine_ttl_s` (statuses
        that do not show in the row, queue places and ETAs)."""
        row, now, key = own_row(self.standings(actor, race), actor.alias), time.monotonic(), (actor.id, race)
        with self._lock:
            hit = self._mine.get(key)
        if hit is not None and hit[0] == row and now - hit[1] < self.mine_ttl_s:
            return hit[2]
        subs = [s.to_json() for s in self.league.submissions(actor, race)]
        with self._lock:
            self._mine[key] = (row, now, subs)
            self._mine.move_to_end(key)
            while len(self._mine) > MAX_MINE:
                self._mine.popitem(last=False)
        return subs


def own_row(standings: dict, alias: str) -> dict | None:
    return next((r for r in standings["rows"] if r["alias"] == alias), None)


def board(boards: Boards, actor: Actor, race: str) -> dict:
    """What a race page shows live: the race, its standings, the caller's own submissions in it."""
    standings = boards.standings(actor, race)
    row = own_row(standings, actor.alias)
    mine = [{k: v for k, v in s.items() if k in MINE_KEYS} for s in boards.mine(actor, race)]
    used = row["submissions"] if row else 0
    return {"race": {**boards.meta(actor, race), "version": standings["version"], "submissions_used": used},
            "standings": standings, "mine": mine}


async def board_events(request, actor: Actor, race: str, poll_s: float = POLL_S, refresh_s: float = REFRESH_S,
                       gap_s: float = MIN_GAP_S):
    boards: Boards = request.app.state.boards
    last, sent = None, 0.0
    while not await request.is_disconnected():
        try:
            await recheck(request, actor)
            version = boards.version_held(actor, race)
            if version is None:
                version = await run_in_threadpool(boards.version, actor, race)
            now = time.monotonic()
            moved = last is not None and version != last["race"]["version"] and now - sent >= gap_s
            if moved or now - sent >= refresh_s:
                last = await run_in_threadpool(board, boards, actor, race)
                sent = time.monotonic()
                yield sse("board", last)
        except LeagueError as exc:
            yield sse("error", {"error": str(exc), "status": exc.status})
            return
        await asyncio.sleep(poll_s)
