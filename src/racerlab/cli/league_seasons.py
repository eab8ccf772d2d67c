"""`racerlab league season ...` and `racerlab league final ...`: seasons of races and head-to-model finals, on a
league folder DIR on this machine, as its admin (see racerlab.league.seasons, racerlab.league.finals)."""

from __future__ import annotations

import json


def register(cmds, dir_flags, open_league) -> None:
    """The `season` and `final` commands under `racerlab league` (`dir_flags` adds DIR/--db/--as, `open_league`
    opens the league and its acting admin)."""
    _season(cmds, dir_flags, open_league)
    _final(cmds, dir_flags, open_league)


def _season(cmds, dir_flags, open_league) -> None:
    p = cmds.add_parser("season", help="seasons: races whose points per place add up to overall standings")
    sc = p.add_subparsers(dest="season_command", metavar="ACTION")
    c = sc.add_parser("create", help="a new season (then add races to it)")
    dir_flags(c)
    c.add_argument("name", metavar="NAME")
    c.add_argument("--points", help="points of 1st, 2nd, ... place, e.g. 10,6,3 (default 25,18,15,12,10,8,6,4,2,1)")
    c.add_argument("--description", default="")
    c.set_defaults(func=lambda a: _print(a, open_league, lambda lg, who: lg.create_season(
        who, a.name, a.points, a.description)))
    for action, helptext in (("add", "put a race in the season"), ("remove", "take a race out of the season")):
        r = sc.add_parser(action, help=helptext)
        dir_flags(r)
        r.add_argument("name", metavar="SEASON")
        r.add_argument("race", metavar="RACE")
        method = "season_add_race" if action == "add" else "season_remove_race"
        r.set_defaults(func=lambda a, m=method: _print(a, open_league, lambda lg, who: getattr(lg, m)(
            who, a.name, a.race)))
    u = sc.add_parser("points", help="change a season's points per place")
    dir_flags(u)
    u.add_argument("name", metavar="SEASON")
    u.add_argument("points", metavar="POINTS", help="e.g. 10,6,3")
    u.set_defaults(func=lambda a: _print(a, open_league, lambda lg, who: lg.update_season(who, a.name,
                                                                                        points=a.points)))
    s = sc.add_parser("show", help="a season's overall standings (or every season's, without SEASON)")
    dir_flags(s)
    s.add_argument("name", nargs="?", metavar="SEASON")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=lambda a: _show_seasons(a, open_league))
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def season_table(view: dict) -> str:
    """A season (as JSON: `SeasonView.to_json()`) as a plain-text table: each racer's place in each race."""
    head = f"{view['name']}: {len(view['races'])} races ({', '.join(view['races']) or 'none yet'}); points " \
           f"{','.join(str(p) for p in view['points'])}"
    lines = [head, f"{'rank':>4}  {'racer':<20}  {'points':>6}  {'wins':>4}  places"]
    for r in view["rows"]:
        places = "  ".join("-" if x is None else str(x) for x in r["places"])
        lines.append(f"{r['rank']:>4}  {r['alias']:<20}  {r['points']:>6}  {r['wins']:>4}  {places}")
    return "\n".join(lines)


def _print(args, open_league, call) -> int:
    league, admin = open_league(args)
    print(season_table(call(league, admin).to_json()))
    return 0


def _show_seasons(args, open_league) -> int:
    league, admin = open_league(args)
    views = [league.season(admin, args.name)] if args.name else league.seasons(admin)
    if args.json:
        data = [v.to_json() for v in views]
        print(json.dumps(data[0] if args.name else data, indent=2))
    else:
        print("\n\n".join(season_table(v.to_json()) for v in views) or "no seasons yet")
    return 0


def _final(cmds, dir_flags, open_league) -> None:
    p = cmds.add_parser("final", help="a head-to-model final of a race's top two racers")
    fc = p.add_subparsers(dest="final_command", metavar="ACTION")
    s = fc.add_parser("start", help="race the top two of RACE's leaderboard together, and wait for the result",
                      description="The two best racers of RACE drive their ranked models on its track at once, under "
                                  "its rules; the result is stored and shown on the race's page.")
    dir_flags(s)
    s.add_argument("race", metavar="RACE")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=lambda a: _final_out(a, open_league, lambda lg, who: [lg.start_final(who, a.race)]))
    ls = fc.add_parser("show", help="a race's finals, newest first")
    dir_flags(ls)
    ls.add_argument("race", metavar="RACE")
    ls.add_argument("--json", action="store_true")
    ls.set_defaults(func=lambda a: _final_out(a, open_league, lambda lg, who: lg.finals(who, a.race)))
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def final_text(f: dict) -> str:
    """A final (as JSON: `FinalView.to_json()`) in a few lines: its state, then each car's place and time."""
    who = " vs ".join(f"{e['alias']} (#{e['qualifying_rank']})" for e in f["entrants"])
    lines = [f"final {f['id']} of {f['race']}: {who}: {f['status']}" + (f" ({f['reason']})" if f["reason"] else "")]
    for car in f["order"]:
        how = (f"{car['total_s']:.3f} s" if car["finished"] else
               f"not finished: {car['laps_completed']} laps and {car['progress']:.1f} % of the next")
        lines.append(f"  {car['place']}. {car['alias']:<20} {how}, off-track {car['off_track']}, "
                     f"crashes {car['crashed']}")
    return "\n".join(lines)


def _final_out(args, open_league, call) -> int:
    league, admin = open_league(args)
    views = [v.to_json() for v in call(league, admin)]
    if args.json:
        print(json.dumps(views, indent=2))
    else:
        print("\n".join(final_text(v) for v in views) or "no finals yet")
    return 0 if all(v["status"] != "failed" for v in views[:1]) else 1
