"""`racerlab league ...`: run a club's virtual races from the command line (see racerlab.league, docs/league.md).

The commands here work on a league folder DIR on this machine, as its admin (`--as ALIAS`, default the first
admin): init, race create / list / update, invite, standings, status, replay, audit, work (evaluation workers
in the foreground). The web server and the commands that talk to it over HTTP (serve, login, submit) live in
the same `league` command.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def _dir_flags(p) -> None:
    p.add_argument("dir", type=Path, metavar="DIR", help="the league folder")
    p.add_argument("--db", metavar="URL", help="the database (default: DIR's league.toml, else DIR/league.db); "
                                               "postgresql://user:password@host/db for a PostgreSQL server")
    p.add_argument("--as", dest="as_alias", metavar="ALIAS", help="the admin to act as (default: the first one)")


def register(sub) -> None:
    p = sub.add_parser("league", help="a race server for many racers: races, submissions, standings",
                       description="Run virtual races for many racers: a store of races and racers, a queue of "
                                   "submissions evaluated by racerlab's race rules, standings. See docs/league.md.")
    cmds = p.add_subparsers(dest="league_command", metavar="COMMAND")
    _init(cmds)
    _race(cmds)
    _invite(cmds)
    _standings(cmds)
    _status(cmds)
    _replay(cmds)
    _audit(cmds)
    _work(cmds)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _open(args):
    from racerlab.league import League

    league = League.open(args.dir, args.db)
    return league, league.local_admin(getattr(args, "as_alias", None))


# ---- init ---------------------------------------------------------------------------------------------------
def _init(cmds) -> None:
    p = cmds.add_parser("init", help="create a league: its store and first admin account",
                        description="Create the league's store in DIR (SQLite in DIR, or --db postgresql://...) and "
                                    "its first admin account; prints how to log in.")
    p.add_argument("dir", type=Path, metavar="DIR")
    p.add_argument("--db", metavar="URL", help="a PostgreSQL server instead of SQLite in DIR (kept in DIR/league.toml)")
    p.add_argument("--admin", default="admin", metavar="ALIAS", help="the admin's alias (default admin)")
    p.add_argument("--password-file", type=Path, metavar="FILE",
                   help="read the admin's password from FILE (default: a random one, printed once)")
    p.set_defaults(func=run_init)


def run_init(args) -> int:
    from racerlab.errors import RacerlabError
    from racerlab.league import League

    password = None
    if args.password_file:
        try:
            password = args.password_file.read_text().strip()
        except OSError as exc:
            raise RacerlabError(f"{args.password_file}: cannot read it ({exc.strerror})") from None
    league, password = League.create(args.dir, args.db, admin=args.admin, password=password)
    where = league.store.url if not league.store.is_sqlite else str(args.dir / "league.db")
    print(f"created the league in {args.dir} (store: {where.split('@')[-1]})")
    print(f"admin account: {args.admin}" + ("" if args.password_file else f", password: {password}  (shown once)"))
    print(f"next: racerlab league race create {args.dir} NAME --track reInvent2019_track, then "
          f"racerlab league invite {args.dir} ALIAS, and serve it: racerlab league serve {args.dir} --workers 2")
    league.close()
    return 0


# ---- races --------------------------------------------------------------------------------------------------
def _race(cmds) -> None:
    from racerlab.league.rules import RACE_TYPES, TIMINGS
    from racerlab.spec import SIMULATORS

    p = cmds.add_parser("race", help="create, list or change races")
    rc = p.add_subparsers(dest="race_command", metavar="ACTION")
    c = rc.add_parser("create", help="a new race with frozen rules",
                      description="Create a race. Its rules are frozen and hashed; once it opens only --closes and "
                                  "--max-submissions can change (racerlab league race update).")
    _dir_flags(c)
    c.add_argument("name", metavar="NAME")
    c.add_argument("--track", required=True, help="the track racers train on: a bundled or AWS name, or a file")
    c.add_argument("--eval-track", default="", help="a hidden track the evaluation drives instead")
    c.add_argument("--reverse", action="store_true", help="drive the track the other way round")
    c.add_argument("--type", dest="race_type", choices=RACE_TYPES, default="time_trial")
    c.add_argument("--timing", choices=TIMINGS, default="best_lap",
                   help="best_lap (the fastest completed lap), average_lap (best mean over --min-laps laps in a "
                        "row) or total_time (all --laps laps)")
    c.add_argument("--laps", type=int, default=3, help="laps driven (default 3)")
    c.add_argument("--min-laps", type=int, default=None,
                   help="completed laps a ranked result needs (default 1; average_lap 3; total_time all)")
    c.add_argument("--off-track-penalty", type=float, default=3.0, metavar="S", help="seconds held (default 3)")
    c.add_argument("--collision-penalty", type=float, default=5.0, metavar="S", help="seconds held (default 5)")
    c.add_argument("--max-resets", type=int, default=10_000, help="resets before the run ends (default 10000)")
    c.add_argument("--time-cap", dest="time_cap_s", type=float, default=180.0, metavar="S",
                   help="simulated seconds a run may last (default 180)")
    c.add_argument("--obstacles", type=int, default=0, help="boxes (object_avoidance), placed from --seed")
    c.add_argument("--obstacle-positions", default="", metavar="F,L;...",
                   help="fixed boxes as 'fraction,lane;...' (lane 1 inner, -1 outer), e.g. '0.25,1;0.6,-1'")
    c.add_argument("--bots", type=int, default=0, help="bot cars (head_to_bot)")
    c.add_argument("--bot-speed", type=float, default=0.5, metavar="M/S")
    c.add_argument("--lane-change", action="store_true", help="bot cars change lanes")
    c.add_argument("--car", choices=SIMULATORS, default="droa", help="whose car every racer drives (default droa)")
    c.add_argument("--seed", type=int, default=0, help="the race's seed (boxes, bots; the same for every racer)")
    c.add_argument("--no-video", dest="video", action="store_false", help="no MP4 of each evaluation")
    c.add_argument("--max-submissions", type=int, default=99, help="per racer (default 99, as DRoA)")
    c.add_argument("--opens", help="ISO time with a zone, now or +N[m|h|d] (default now)")
    c.add_argument("--closes", help="ISO time with a zone or +N[m|h|d] (default: open until changed)")
    c.add_argument("--description", default="")
    c.add_argument("--private-videos", dest="public_videos", action="store_false",
                   help="racers see only their own videos (default: the leaderboard's videos are public)")
    c.add_argument("--json", action="store_true", help="print the race as JSON")
    c.set_defaults(func=run_race_create)
    ls = rc.add_parser("list", help="the races and their rules")
    _dir_flags(ls)
    ls.add_argument("--json", action="store_true")
    ls.set_defaults(func=run_race_list)
    u = rc.add_parser("update", help="change a race's close time or submission limit")
    _dir_flags(u)
    u.add_argument("name", metavar="NAME")
    u.add_argument("--closes", help="ISO time with a zone or +N[m|h|d]; 'never' removes the close time")
    u.add_argument("--max-submissions", type=int)
    u.set_defaults(func=run_race_update)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _positions(text: str, where: str = "--obstacle-positions"):
    from racerlab.errors import RacerlabError

    out = []
    for item in filter(None, (t.strip() for t in text.split(";"))):
        try:
            frac, lane = (float(v) for v in item.split(","))
        except ValueError:
            raise RacerlabError(f"{where}: {item!r} is not 'fraction,lane'; write e.g. '0.25,1;0.6,-1'") from None
        out.append((frac, int(lane)))
    return tuple(out)


def run_race_create(args) -> int:
    league, admin = _open(args)
    keys = ("track", "eval_track", "reverse", "race_type", "timing", "laps", "min_laps", "off_track_penalty",
            "collision_penalty", "max_resets", "time_cap_s", "obstacles", "bots", "bot_speed", "lane_change", "car",
            "seed", "video", "max_submissions", "opens", "closes", "description", "public_videos")
    options = {k: getattr(args, k) for k in keys}
    options["obstacle_positions"] = _positions(args.obstacle_positions)
    race = league.create_race(admin, args.name, options)
    print(json.dumps(race.to_json(), indent=2) if args.json else _race_line(race))
    return 0


def _race_line(race) -> str:
    closes = race.to_json()["closes_at"] or "no close time"
    return (f"{race.name} ({race.state}): {race.summary}; {race.max_submissions} submissions per racer; opens "
            f"{race.to_json()['opens_at']}, closes {closes}; rules {race.rules_hash[:12]}")


def run_race_list(args) -> int:
    league, admin = _open(args)
    races = league.races(admin)
    if args.json:
        print(json.dumps([r.to_json() for r in races], indent=2))
    else:
        print("\n".join(_race_line(r) for r in races) or "no races yet")
    return 0


def run_race_update(args) -> int:
    from racerlab.league.service import KEEP

    league, admin = _open(args)
    closes = KEEP if args.closes is None else (None if args.closes == "never" else args.closes)
    limit = KEEP if args.max_submissions is None else args.max_submissions
    print(_race_line(league.update_race(admin, args.name, closes=closes, max_submissions=limit)))
    return 0


# ---- people -------------------------------------------------------------------------------------------------
def _invite(cmds) -> None:
    from racerlab.league import ROLES

    p = cmds.add_parser("invite", help="a one-time invite for a racer (or staff)")
    _dir_flags(p)
    p.add_argument("alias", metavar="ALIAS", help="the new account's alias: 3-20 letters, digits, _ or -")
    p.add_argument("--role", choices=ROLES, default="racer")
    p.set_defaults(func=run_invite)


def run_invite(args) -> int:
    league, admin = _open(args)
    inv = league.invite(admin, args.alias, args.role)
    print(f"invite for {inv.alias} ({inv.role}), valid until {inv.to_json()['expires_at']}, usable once:")
    print(f"  {inv.code}")
    print(f"{inv.alias} accepts it with: racerlab league login URL --invite {inv.code}  (or on the league's page)")
    return 0


# ---- results ------------------------------------------------------------------------------------------------
def _standings(cmds) -> None:
    p = cmds.add_parser("standings", help="a race's standings as a table, JSON or CSV")
    _dir_flags(p)
    p.add_argument("race", metavar="RACE")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--json", action="store_true")
    fmt.add_argument("--csv", action="store_true")
    p.add_argument("-o", "--output", type=Path, help="write to this file instead of printing")
    p.set_defaults(func=run_standings)


def standings_table(st) -> str:
    lines = [f"{st.race}: {st.timing.replace('_', ' ')}, {st.state} (rules {st.rules_hash[:12]})",
             f"{'rank':>4}  {'racer':<20}  {'time':>8}  {'gap':>7}  {'laps':>5}  {'off-track':>9}  {'subs':>4}  status"]
    for r in st.rows:
        t = "-" if r.time_s is None else f"{r.time_s:.3f}"
        gap = "" if r.gap_s is None else f"+{r.gap_s:.3f}"
        laps = f"{r.laps_completed or 0}/{r.laps_driven or 0}"
        lines.append(f"{r.rank or '-':>4}  {r.alias:<20}  {t:>8}  {gap:>7}  {laps:>5}  {r.off_track or 0:>9}  "
                     f"{r.submissions:>4}  {r.status.replace('_', ' ')}")
    return "\n".join(lines)


def run_standings(args) -> int:
    from racerlab.logs import atomic_write_text

    league, admin = _open(args)
    if args.csv:
        text = league.standings_csv(admin, args.race)
    else:
        st = league.standings(admin, args.race)
        text = json.dumps(st.to_json(), indent=2) + "\n" if args.json else standings_table(st) + "\n"
    if args.output:
        atomic_write_text(args.output, text)
        print(f"wrote {args.output}")
    else:
        sys.stdout.write(text)
    return 0


def _status(cmds) -> None:
    p = cmds.add_parser("status", help="the queue and the submissions of a league folder")
    _dir_flags(p)
    p.add_argument("race", nargs="?", metavar="RACE")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run_status)


def run_status(args) -> int:
    league, admin = _open(args)
    subs = league.submissions(admin, args.race, everyone=True)
    q = league.queue(admin)
    if args.json:
        print(json.dumps({"queue": q.to_json(), "submissions": [s.to_json() for s in subs]}, indent=2))
        return 0
    mean = "-" if q.mean_eval_s is None else f"{q.mean_eval_s:.1f} s"
    print(f"queue: {q.queued} queued, {q.evaluating} under evaluation, {q.workers} workers, mean evaluation {mean}")
    for s in subs:
        place = f" #{s.position} in the queue" + (f", ETA {s.eta_s:.0f} s" if s.eta_s is not None else "") \
            if s.status == "queued" else ""
        print(f"{s.id:>5}  {s.race:<16} {s.alias:<20} #{s.number:<3} {s.status_text}{place}: {s.reason}")
    return 0


def _replay(cmds) -> None:
    p = cmds.add_parser("replay", help="evaluate a stored result again and check its laps bit for bit")
    _dir_flags(p)
    p.add_argument("result", metavar="RESULT", help="the submission's id (as `league status` lists it)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run_replay)


def run_replay(args) -> int:
    from racerlab.errors import RacerlabError

    league, admin = _open(args)
    try:
        sid = int(str(args.result).lstrip("#"))
    except ValueError:
        raise RacerlabError(f"RESULT {args.result!r}: give a submission id, e.g. 12") from None
    report = league.replay(admin, sid)
    print(json.dumps(report.to_json(), indent=2) if args.json else report.text())
    return 0 if report.identical else 1


def _audit(cmds) -> None:
    p = cmds.add_parser("audit", help="the append-only log of admin actions and results")
    _dir_flags(p)
    p.add_argument("--since", type=int, default=0, metavar="ID")
    p.add_argument("--limit", type=int, default=200)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run_audit)


def run_audit(args) -> int:
    league, admin = _open(args)
    rows = league.audit(admin, args.since, args.limit)
    if args.json:
        print(json.dumps([r.to_json() for r in rows], indent=2))
    for r in [] if args.json else rows:
        print(f"{r.id:>6}  {r.to_json()['at']}  {r.actor:<24} {r.action:<20} {r.subject}")
    return 0


def _work(cmds) -> None:
    p = cmds.add_parser("work", help="evaluation workers in the foreground (Ctrl-C stops them)",
                        description="Evaluate the league's queue with N local worker processes until Ctrl-C; "
                                    "`league serve --workers N` starts the same workers beside the web server.")
    _dir_flags(p)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--until-empty", action="store_true", help="stop when the queue is empty")
    p.set_defaults(func=run_work)


def run_work(args) -> int:
    import time

    from racerlab.league import start_workers

    league, admin = _open(args)
    pool = start_workers(args.dir, args.db, args.workers)
    print(f"{args.workers} worker(s) on {args.dir}; Ctrl-C stops them (an evaluation under way is queued again)")
    try:
        while True:
            time.sleep(2.0)
            q = league.queue(admin)
            if args.until_empty and q.queued == 0 and q.evaluating == 0:
                break
    except KeyboardInterrupt:
        print("stopping the workers ...", file=sys.stderr)
    finally:
        pool.stop()
    return 0

