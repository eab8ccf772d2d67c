"""A race's live board as server-sent events: the standings and the caller's own submissions in that race.

`board_events` looks at the race's version (`League.race_version`: it changes with every status and result of the
race) every `POLL_S` and sends a `board` event when it moved, and every `REFRESH_S` anyway (queue places and ETAs
move with other races' work; the event doubles as a keep-alive). Each look goes through the service with the
caller's account, so a disabled account's stream ends at the next look (an `error` event says why). Nothing runs
for a browser that is not connected.
"""

from __future__ import annotations

import asyncio
import json
import time

from starlette.concurrency import run_in_threadpool

from racerlab.league.people import Actor
from racerlab.league.store import LeagueError

POLL_S = 0.5
REFRESH_S = 10.0
MINE_KEYS = ("id", "number", "model_name", "model_hash", "checkpoint", "created_at", "status", "status_text",
             "reason", "position", "eta_s", "score_ms", "laps_completed", "laps_driven", "off_track", "note")


def sse(event: str, data) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'), allow_nan=False)}\n\n"


def board(league, actor: Actor, race: str) -> dict:
    """What a race page shows live: the race (state, version, the caller's count), its standings, the caller's
    own submissions in it (newest first)."""
    view = league.race(actor, race)
    mine = [{k: v for k, v in s.to_json().items() if k in MINE_KEYS} for s in league.submissions(actor, race)]
    return {"race": {"name": view.name, "state": view.state, "version": view.version,
                     "submissions_used": view.submissions_used, "max_submissions": view.max_submissions},
            "standings": league.standings(actor, race).to_json(), "mine": mine}


async def board_events(request, actor: Actor, race: str, poll_s: float = POLL_S, refresh_s: float = REFRESH_S):
    league = request.app.state.league
    last, sent = None, 0.0
    while not await request.is_disconnected():
        try:
            version = await run_in_threadpool(league.race_version, actor, race)
            if version != last or time.monotonic() - sent >= refresh_s:
                data = await run_in_threadpool(board, league, actor, race)
                last, sent = data["race"]["version"], time.monotonic()
                yield sse("board", data)
        except LeagueError as exc:
            yield sse("error", {"error": str(exc), "status": exc.status})
            return
        await asyncio.sleep(poll_s)
