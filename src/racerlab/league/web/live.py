"""A race's live board as server-sent events, and what the many browsers of one race share in this process.

On race day a hundred racers keep the race's page open and scripts poll its standings; asking the database for
each of them would cost a core. `Boards` shares the work:

- the race's version (`League.race_version`: it changes with every status and result of the race) is read at most
  every `POLL_S` per race, whoever asks, and at once after a submission, requeue or race change made through this
  server (`touch`);
- the standings and the race's limits are read once per version and handed to every asker (they are the same for
  everyone); the race's state (upcoming, open, closed) is worked out from its times at each hand-out, since it
  moves with the clock, not the version;
- the racers' own submissions in the race are read for all of them at once (`League.race_submissions`), again when
  the race's version moved and at least every `MINE_TTL_S` (queue places and ETAs move with other races too), and
  each asker is handed their own list alone: a hundred racers' polls each reading their own list cost the server
  a core on race day (the profile of benchmarks/league_web.py).

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
        self._mine: dict[str, tuple[int, float, dict[int, list[dict]]]] = {}  # race -> (version, read at, lists)

    def touch(self) -> None:
        """A change made through this server: the next look at any race asks the store for its version, and so
        reads its standings and the racers' lists again when they moved (every change a board shows moves its
        race's version, whoever made it)."""
        with self._lock:
            self._versions.clear()

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
        people.require_role(actor, "submission.create")
        version = self.version_held(actor, race)
        if version is None:
            return None
        with self._lock:
            hit = self._mine.get(race)
        return hit[2].get(actor.id, []) if self._mine_current(hit, version) else None

    def _mine_current(self, hit, version: int) -> bool:
        return hit is not None and hit[0] >= version and time.monotonic() - hit[1] < self.mine_ttl_s

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
        """The actor's own submissions in the race as JSON (newest first), out of everyone's lists read at once:
        again when the race's version moved and at least every `mine_ttl_s` (queue places and ETAs)."""
        people.require_role(actor, "submission.create")
        version = self.version(actor, race)

        def read() -> tuple[int, float, dict[int, list[dict]]]:
            at = time.monotonic()
            lists = self.league.race_submissions(race)
            return version, at, {user: [s.to_json() for s in subs] for user, subs in lists.items()}

        return self._through("mine", race, self._mine, lambda h: self._mine_current(h, version), read)[2].get(
            actor.id, [])


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
