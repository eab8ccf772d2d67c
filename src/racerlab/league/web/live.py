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

    def _one_reader(self, kind: str, race: str) -> threading.Lock:
        """The lock under which one thread reads `kind` of `race` from the store while the others wait for its
        answer (a crowd's polls that miss together would otherwise each read the same rows)."""
        with self._lock:
            return self._readers.setdefault((kind, race), threading.Lock())

    def _held_version(self, race: str) -> int | None:
        with self._lock:
            hit = self._versions.get(race)
        return hit[0] if hit is not None and time.monotonic() - hit[1] < self.poll_s else None

    def version(self, actor: Actor, race: str) -> int:
        people.require_role(actor, "race.view")
        version = self._held_version(race)
        if version is not None:
            return version
        with self._one_reader("version", race):
            version = self._held_version(race)
            if version is not None:
                return version
            now = time.monotonic()
            version = self.league.race_version(actor, race)  # 404 for a race that is not there
            with self._lock:
                self._versions[race] = (version, now)
        return version

    def standings(self, actor: Actor, race: str) -> dict:
        """The race's standings as JSON (`Standings.to_json()`), read once per version."""
        version = self.version(actor, race)
        people.require_role(actor, "standings.view")
        with self._lock:
            hit = self._standings.get(race)
        if hit is None or hit["version"] < version:
            with self._one_reader("standings", race):
                with self._lock:
                    hit = self._standings.get(race)
                if hit is None or hit["version"] < version:
                    hit = self.league.standings(actor, race).to_json()
                    with self._lock:
                        held = self._standings.get(race)
                        if held is None or held["version"] <= hit["version"]:
                            self._standings[race] = hit
        return {**hit, "state": self.meta(actor, race)["state"]}

    # ---- from memory alone, on the event loop: None when only the store can say ------------------------------
    def _fresh(self, race: str) -> tuple[int, dict, dict] | None:
        """(version, standings, race meta) held and still fresh (the version read within `poll_s`)."""
        now = time.monotonic()
        with self._lock:
            held, standings, meta = self._versions.get(race), self._standings.get(race), self._races.get(race)
        if held is None or now - held[1] >= self.poll_s or standings is None or meta is None:
            return None
        if standings["version"] < held[0] or meta[0] < held[0]:
            return None
        return held[0], standings, meta[1]

    def standings_json_held(self, actor: Actor, race: str) -> bytes | None:
        """`standings_json` when it needs no read of the store; None otherwise (then call `standings_json`)."""
        people.require_role(actor, "race.view")
        people.require_role(actor, "standings.view")
        fresh = self._fresh(race)
        if fresh is None:
            return None
        version, standings, meta = fresh
        state = race_state(meta["opens_at"], meta["closes_at"], utcnow())
        with self._lock:
            hit = self._encoded.get(race)
        return hit[1] if hit is not None and hit[0] == (standings["version"], state) else None

    def mine_held(self, actor: Actor, race: str) -> list[dict] | None:
        """`mine` when it needs no read of the store; None otherwise (then call `mine`)."""
        people.require_role(actor, "race.view")
        people.require_role(actor, "standings.view")
        fresh = self._fresh(race)
        if fresh is None:
            return None
        row, now = own_row(fresh[1], actor.alias), time.monotonic()
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
        with self._lock:
            hit = self._races.get(race)
        if hit is None or hit[0] < version:
            with self._one_reader("race", race):
                with self._lock:
                    hit = self._races.get(race)
                if hit is None or hit[0] < version:
                    view = self.league.race(actor, race)
                    hit = (view.version, {"name": view.name, "max_submissions": view.max_submissions,
                                          "opens_at": view.opens_at, "closes_at": view.closes_at})
                    with self._lock:
                        self._races[race] = hit
        held = hit[1]
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
