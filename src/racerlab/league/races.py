"""Creating and changing a race: the options a facilitator gives (form or command line), their times, the window.

`RaceOptions` is everything `League.create_race` takes, with one-line errors for unknown keys and bad values;
`RaceOptions.rules()` turns it into `Rules` (tracks not yet pinned). Times are ISO 8601 with a time zone
(`2026-05-01T18:00+02:00`, `...Z`), `now`, or `+N` minutes / hours / days from now (`+90m`, `+2h`, `+14d`); a
time without a zone is refused rather than guessed.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, fields
from datetime import UTC, datetime, timedelta

from racerlab.league.rules import RACE_TYPES, TIMINGS, Rules, objects_table
from racerlab.league.store import LeagueError
from racerlab.spec import DEFAULT_SIMULATOR

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9 ._-]{0,63}$")
DEFAULT_MAX_SUBMISSIONS = 99  # DRoA's default
MAX_SUBMISSIONS = 10_000


@dataclass
class RaceOptions:
    """A new race, as a facilitator describes it. `track` and `eval_track`: a bundled or AWS name, or a file."""

    track: str
    race_type: str = "time_trial"
    timing: str = "best_lap"
    laps: int = 3
    min_laps: int | None = None  # None: 1 for best lap, 3 (or laps) for an average, laps for total time
    off_track_penalty: float = 3.0
    collision_penalty: float = 5.0
    max_resets: int = 10_000
    time_cap_s: float = 180.0
    reverse: bool = False
    eval_track: str = ""
    obstacles: int = 0
    obstacle_positions: tuple = ()  # ((fraction of the lap, lane 1 | -1), ...); none: drawn from the seed
    bots: int = 0
    bot_speed: float = 0.5
    lane_change: bool = False
    car: str = DEFAULT_SIMULATOR
    seed: int = 0
    video: bool = True
    opens: str | datetime | None = None  # None: now
    closes: str | datetime | None = None  # None: open until a facilitator sets a close time
    max_submissions: int = DEFAULT_MAX_SUBMISSIONS
    description: str = ""
    public_videos: bool = True

    @classmethod
    def from_mapping(cls, data: dict) -> RaceOptions:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise LeagueError(f"race option {unknown[0]!r} is not one of {', '.join(sorted(known))}")
        if "track" not in data or not data["track"]:
            raise LeagueError("a race needs a track: give a bundled or AWS track name, or a track file")
        return cls(**data)

    def resolved_min_laps(self) -> int:
        if self.min_laps is not None:
            return self.min_laps
        if self.timing == "total_time":
            return self.laps
        return min(3, self.laps) if self.timing == "average_lap" else 1

    def rules(self) -> Rules:
        """The frozen rules (tracks still to be pinned by `rules.with_tracks`)."""
        if self.race_type not in RACE_TYPES:
            raise LeagueError(f"race type {self.race_type!r}: use one of {', '.join(RACE_TYPES)}")
        if self.timing not in TIMINGS:
            raise LeagueError(f"timing {self.timing!r}: use one of {', '.join(TIMINGS)}")
        race = objects_table(self.race_type, self.obstacles, tuple(self.obstacle_positions), self.bots,
                             self.bot_speed, self.lane_change)
        return Rules(track="", track_sha256="", reverse=bool(self.reverse), race_type=self.race_type,
                     timing=self.timing, laps=self.laps, min_laps=self.resolved_min_laps(),
                     off_track_penalty=float(self.off_track_penalty), collision_penalty=float(self.collision_penalty),
                     max_resets=self.max_resets, time_cap_s=float(self.time_cap_s), race=race, car=self.car,
                     seed=self.seed, video=bool(self.video))

    def schedule(self, now: datetime) -> tuple[datetime, datetime | None]:
        opens = parse_time(self.opens, now, "opens") if self.opens else now
        closes = parse_time(self.closes, now, "closes") if self.closes else None
        if closes is not None and closes <= opens:
            raise LeagueError(f"the race closes ({iso(closes)}) before it opens ({iso(opens)}); give a later "
                              "close time")
        return opens, closes


def check_name(name: str) -> str:
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise LeagueError(f"race name {name!r}: 1-64 letters, digits, spaces, '.', '_' or '-', starting with a "
                          "letter or digit")
    return name


def check_limit(n) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_SUBMISSIONS:
        raise LeagueError(f"submissions per racer must be a whole number from 1 to {MAX_SUBMISSIONS}, got {n!r}")
    return n


_RELATIVE = re.compile(r"^\+(\d+(?:\.\d+)?)([mhd])$")


def parse_time(value, now: datetime, what: str = "time") -> datetime:
    """An aware UTC datetime from a datetime, ISO 8601 text with a zone, `now` or `+N[m|h|d]`."""
    if isinstance(value, datetime):
        if value.tzinfo is None:
            raise LeagueError(f"{what}: {value.isoformat()} has no time zone; add one (e.g. +00:00)")
        return value.astimezone(UTC)
    text = str(value).strip()
    if text == "now":
        return now
    m = _RELATIVE.match(text)
    if m:
        unit = {"m": "minutes", "h": "hours", "d": "days"}[m.group(2)]
        return now + timedelta(**{unit: float(m.group(1))})
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise LeagueError(f"{what}: {text!r} is not a time; write e.g. 2026-05-01T18:00+02:00, now or +2h") from None
    if t.tzinfo is None:
        raise LeagueError(f"{what}: {text!r} has no time zone; add one (e.g. {text}+00:00 or {text}Z)")
    return t.astimezone(UTC)


def iso(t: datetime | None) -> str | None:
    return None if t is None else t.astimezone(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def race_state(opens: datetime, closes: datetime | None, now: datetime) -> str:
    """upcoming | open | closed."""
    if now < opens:
        return "upcoming"
    if closes is not None and now >= closes:
        return "closed"
    return "open"
