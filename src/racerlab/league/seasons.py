"""Seasons: several races whose standings add up, by the points each place earns, into one overall table.

A season holds races (each race in at most one season) and a points table: the points of 1st, 2nd, ... place
(`DEFAULT_POINTS` unless staff give their own; a place past the table's end earns 0). A race's places are its
leaderboard's ranks (`racerlab.league.scoring`: each racer's best ranked submission, ties to the earlier one); a
racer with no ranked result in a race, or who did not enter it, gets 0 for it.

The overall order (`season_table`), one rule with no ties left: more points; then countback (more 1st places,
then more 2nd places, and so on); then the earlier result (the earliest submission time among the racer's ranked
results in the season's races); then the older account. The AWS DeepRacer League's own points table is not in
the public material racerlab's reference holds (docs/league.md, "Seasons and finals").
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from racerlab.league import audit
from racerlab.league.people import Actor, require_role
from racerlab.league.races import check_name
from racerlab.league.store import LeagueError
from racerlab.league.tables import Race, Season, SeasonRace, User
from racerlab.league.views import SeasonRow, SeasonView

DEFAULT_POINTS = (25, 18, 15, 12, 10, 8, 6, 4, 2, 1)  # a common motorsport table: the default, a season setting
MAX_PLACES = 100
MAX_POINTS = 10_000


def check_points(points) -> list[int]:
    """A points table: 1-100 whole numbers from 0 to 10 000, none larger than the one before (text "25,18,15"
    or a list)."""
    if isinstance(points, str):
        try:
            points = [int(p) for p in points.replace(" ", "").split(",") if p != ""]
        except ValueError:
            raise LeagueError(f"points {points!r}: write the points of 1st, 2nd, ... place as whole numbers, "
                              "e.g. 25,18,15,12,10") from None
    if not isinstance(points, list | tuple) or not 1 <= len(points) <= MAX_PLACES:
        raise LeagueError(f"points: give the points of 1 to {MAX_PLACES} places, e.g. 25,18,15,12,10")
    for k, p in enumerate(points):
        if isinstance(p, bool) or not isinstance(p, int) or not 0 <= p <= MAX_POINTS:
            raise LeagueError(f"points of place {k + 1}: a whole number from 0 to {MAX_POINTS}, got {p!r}")
        if k and p > points[k - 1]:
            raise LeagueError(f"points of place {k + 1} ({p}) are more than those of place {k} ({points[k - 1]}); "
                              "a lower place cannot earn more")
    return list(points)


@dataclass(frozen=True)
class Place:
    """A racer's place in one race of a season."""

    user_id: int
    alias: str
    rank: int
    submitted_at: float  # epoch seconds of the ranked submission


def season_table(points: list[int], boards: list[list[Place]]) -> list[SeasonRow]:
    """The overall standings of races whose places are `boards` (one list per race, in the season's order)."""
    n = len(boards)
    seen: dict[int, dict] = {}
    for k, board in enumerate(boards):
        for p in board:
            r = seen.setdefault(p.user_id, {"alias": p.alias, "places": [None] * n, "first": math.inf})
            r["places"][k] = p.rank
            r["first"] = min(r["first"], p.submitted_at)
    deepest = max((p.rank for board in boards for p in board), default=0)

    def earned(rank: int | None) -> int:
        return points[rank - 1] if rank is not None and rank <= len(points) else 0

    def key(item):
        uid, r = item
        countback = [-sum(1 for x in r["places"] if x == place) for place in range(1, deepest + 1)]
        return (-sum(earned(x) for x in r["places"]), countback, r["first"], uid)

    out = []
    for rank, (_, r) in enumerate(sorted(seen.items(), key=key), 1):
        race_points = [earned(x) for x in r["places"]]
        out.append(SeasonRow(rank, r["alias"], sum(race_points), r["places"], race_points,
                             sum(1 for x in r["places"] if x == 1)))
    return out


class SeasonsMixin:
    """`League`'s season calls (see `racerlab.league.service.League`)."""

    def create_season(self, actor: Actor, name: str, points=None, description: str = "") -> SeasonView:
        """A new season (no races yet) with `points` per place (default `DEFAULT_POINTS`)."""
        require_role(actor, "season.edit")
        check_name(name)
        table = check_points(list(DEFAULT_POINTS) if points is None else points)
        try:
            with self.store.write() as s:
                self._acting(s, actor, "season.edit")
                s.add(Season(name=name, description=str(description or "")[:255], points_json=json.dumps(table),
                             created_by=actor.id))
                s.flush()
                audit.record(s, actor, "season.create", f"season:{name}", points=table)
        except IntegrityError:
            raise LeagueError(f"a season named {name!r} exists; choose another name", 409) from None
        return self.season(actor, name)

    def update_season(self, actor: Actor, name: str, *, points=None, description: str | None = None) -> SeasonView:
        """Change a season's points table or description (the standings follow at once)."""
        with self.store.write() as s:
            self._acting(s, actor, "season.edit")
            season = self._season_row(s, name)
            changes = {}
            if points is not None:
                season.points_json = json.dumps(changes.setdefault("points", check_points(points)))
            if description is not None:
                season.description = changes["description"] = str(description)[:255]
            if not changes:
                raise LeagueError("nothing to change: give points or a description")
            audit.record(s, actor, "season.update", f"season:{name}", **changes)
        return self.season(actor, name)

    def season_add_race(self, actor: Actor, name: str, race: str) -> SeasonView:
        """Put `race` in the season (a race belongs to one season at most)."""
        with self.store.write() as s:
            self._acting(s, actor, "season.edit")
            season, row = self._season_row(s, name), self._race_row(s, race)
            held = s.get(SeasonRace, {"season_id": season.id, "race_id": row.id}) or s.scalars(
                select(SeasonRace).where(SeasonRace.race_id == row.id)).first()
            if held is not None:
                other = s.get(Season, held.season_id).name
                raise LeagueError(f"race {row.name!r} is already in season {other!r}; a race counts in one season",
                                  409)
            s.add(SeasonRace(season_id=season.id, race_id=row.id))
            audit.record(s, actor, "season.add_race", f"season:{name}", race=row.name)
        return self.season(actor, name)

    def season_remove_race(self, actor: Actor, name: str, race: str) -> SeasonView:
        with self.store.write() as s:
            self._acting(s, actor, "season.edit")
            season, row = self._season_row(s, name), self._race_row(s, race)
            held = s.get(SeasonRace, {"season_id": season.id, "race_id": row.id})
            if held is None:
                raise LeagueError(f"race {row.name!r} is not in season {name!r}", 404)
            s.delete(held)
            audit.record(s, actor, "season.remove_race", f"season:{name}", race=row.name)
        return self.season(actor, name)

    def season(self, actor: Actor, name: str) -> SeasonView:
        """A season, its races and its overall standings (everyone who may see the races' leaderboards)."""
        with self.store.read() as s:
            self._acting(s, actor, "standings.view")
            return self._season_view(s, self._season_row(s, name))

    def seasons(self, actor: Actor) -> list[SeasonView]:
        with self.store.read() as s:
            self._acting(s, actor, "standings.view")
            return [self._season_view(s, r) for r in s.scalars(select(Season).order_by(Season.id))]

    def _season_row(self, s: Session, name: str) -> Season:
        season = s.scalars(select(Season).where(Season.name == str(name))).first()
        if season is None:
            raise LeagueError(f"no season named {name!r}; `racerlab league season list DIR` lists them", 404)
        return season

    def _season_view(self, s: Session, season: Season) -> SeasonView:
        from racerlab.league.submissions import race_rows

        races = s.scalars(select(Race).join(SeasonRace, SeasonRace.race_id == Race.id)
                          .where(SeasonRace.season_id == season.id)
                          .order_by(SeasonRace.added_at, SeasonRace.race_id)).all()
        ids = dict(s.execute(select(User.alias, User.id)).all())
        boards = []
        for race in races:
            boards.append([Place(ids[r.alias], r.alias, r.rank, r.submitted_at.timestamp())
                           for r in race_rows(s, race) if r.rank is not None])
        points = json.loads(season.points_json)
        return SeasonView(season.name, season.description, points, [r.name for r in races],
                          season_table(points, boards))
