"""`racerlab league ...`: run a club's virtual races from the command line (see racerlab.league, docs/league.md).

On a league folder DIR on this machine, as its admin (`--as ALIAS`, default the first admin): init, race create /
list / update, invite, standings, season and final (`cli.league_seasons`), status, replay, audit, work
(evaluation workers in the foreground), serve (the web pages, the HTTP API and local workers). Over HTTP, with the
API token `login` stores in the user's config folder: login (an invite or a password), submit, status and
standings (without DIR: the server logged in to).
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
    _serve(cmds)
    _login(cmds)
    _submit(cmds)
    from racerlab.cli import league_seasons

    league_seasons.register(cmds, _dir_flags, _open)
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
def _where_flags(p) -> None:
    """The flags of a command that reads a league folder DIR here or, without one, the server logged in to."""
    p.add_argument("--db", metavar="URL", help="with DIR: the database (default: DIR's league.toml, else "
                                               "DIR/league.db)")
    p.add_argument("--as", dest="as_alias", metavar="ALIAS", help="with DIR: the admin to act as")
    _url_flag(p)


def is_league_folder(path: Path) -> bool:
    from racerlab.league.store import CONFIG_NAME, DB_NAME

    return (path / DB_NAME).is_file() or (path / CONFIG_NAME).is_file()


def _standings(cmds) -> None:
    p = cmds.add_parser("standings", help="a race's standings as a table, JSON or CSV",
                        description="The standings of RACE: of the league folder DIR on this machine, or, without "
                                    "DIR, from the league server you logged in to (racerlab league login).")
    p.add_argument("dir", nargs="?", type=Path, metavar="DIR", help="a league folder here (default: the server)")
    p.add_argument("race", metavar="RACE")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--json", action="store_true")
    fmt.add_argument("--csv", action="store_true")
    p.add_argument("-o", "--output", type=Path, help="write to this file instead of printing")
    _where_flags(p)
    p.set_defaults(func=run_standings)


def standings_table(st: dict) -> str:
    """A race's standings (as JSON: `Standings.to_json()`) as a plain-text table."""
    lines = [f"{st['race']}: {st['timing'].replace('_', ' ')}, {st['state']} (rules {st['rules_hash'][:12]})",
             f"{'rank':>4}  {'racer':<20}  {'time':>8}  {'gap':>7}  {'laps':>5}  {'off-track':>9}  {'subs':>4}  status"]
    for r in st["rows"]:
        t = "-" if r["time_s"] is None else f"{r['time_s']:.3f}"
        gap = "" if r["gap_s"] is None else f"+{r['gap_s']:.3f}"
        laps = f"{r['laps_completed'] or 0}/{r['laps_driven'] or 0}"
        lines.append(f"{r['rank'] or '-':>4}  {r['alias']:<20}  {t:>8}  {gap:>7}  {laps:>5}  {r['off_track'] or 0:>9}  "
                     f"{r['submissions']:>4}  {r['status'].replace('_', ' ')}")
    return "\n".join(lines)


def run_standings(args) -> int:
    from racerlab.logs import atomic_write_text

    if args.dir is None:
        from racerlab.league.client import Client

        client = Client.stored(args.url)
        csv_text, standings = client.standings_csv, client.standings
    else:
        league, admin = _open(args)
        csv_text = lambda race: league.standings_csv(admin, race)  # noqa: E731
        standings = lambda race: league.standings(admin, race).to_json()  # noqa: E731
    if args.csv:
        text = csv_text(args.race)
    else:
        st = standings(args.race)
        text = json.dumps(st, indent=2) + "\n" if args.json else standings_table(st) + "\n"
    if args.output:
        atomic_write_text(args.output, text)
        print(f"wrote {args.output}")
    else:
        sys.stdout.write(text)
    return 0


def _status(cmds) -> None:
    p = cmds.add_parser("status", help="submissions and what became of them: a league folder's, or yours on a server",
                        description="With a league folder DIR: the queue and every submission (as its admin). "
                                    "Without: your own submissions on the league server you logged in to.")
    p.add_argument("dir", nargs="?", metavar="DIR", help="a league folder here (default: the server)")
    p.add_argument("race", nargs="?", metavar="RACE", help="only this race")
    p.add_argument("--json", action="store_true")
    _where_flags(p)
    p.set_defaults(func=run_status)


def run_status(args) -> int:
    from racerlab.errors import RacerlabError

    if args.dir is not None and not is_league_folder(Path(args.dir)):
        if args.race is not None:
            raise RacerlabError(f"{args.dir}: not a league folder (no league.db or league.toml in it)")
        args.dir, args.race = None, args.dir  # `status RACE`: a race on the server logged in to
    if args.dir is None:
        return run_http_status(args)
    args.dir = Path(args.dir)
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


def run_http_status(args) -> int:
    from racerlab.league.client import Client

    subs = Client.stored(args.url).submissions(args.race)
    if args.json:
        print(json.dumps({"submissions": subs}, indent=2))
    else:
        print("\n".join(submission_line(s) for s in subs) or "no submissions yet")
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


# ---- over HTTP: the server logged in to -----------------------------------------------------------------------
def _url_flag(p) -> None:
    p.add_argument("--url", metavar="URL", help="the league server (default: the one you logged in to last)")


# ---- serve ----------------------------------------------------------------------------------------------------
def _serve(cmds) -> None:
    p = cmds.add_parser("serve", help="the league's web pages and API, and evaluation workers",
                        description="Serve the league in DIR: its pages (races, live leaderboards, uploads, staff "
                                    "pages) and the HTTP API `league login | submit | status | standings` use. "
                                    "Loopback only by default; any other --host needs TLS (--tls-cert, --tls-key).")
    p.add_argument("dir", type=Path, metavar="DIR", help="the league folder (racerlab league init DIR)")
    p.add_argument("--db", metavar="URL", help="the database (default: DIR's league.toml, else DIR/league.db)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="local evaluation workers started beside the server (default 0: `racerlab league work`)")
    p.add_argument("--ray", metavar="ADDRESS",
                   help="send the evaluations to the Ray cluster whose head is at ADDRESS (HOST:PORT, as `ray start "
                        "--head` prints it) instead of local workers; needs racerlab[cluster]")
    p.add_argument("--ray-workers", type=int, metavar="N",
                   help="evaluations at once on the Ray cluster (default: its CPUs, as machines join or leave)")
    p.add_argument("--tls-cert", type=Path, metavar="FILE", help="the server's certificate (PEM)")
    p.add_argument("--tls-key", type=Path, metavar="FILE", help="its private key (PEM)")
    p.add_argument("--public-url", metavar="URL",
                   help="the https:// address of a TLS proxy in front of a loopback server (its host is accepted, "
                        "invite links name it)")
    p.set_defaults(func=run_serve)


def run_serve(args) -> int:
    from racerlab.errors import RacerlabError

    try:
        from racerlab.league.web.server import serve
    except ImportError as exc:
        raise RacerlabError(f"league serve needs the league's web stack ({exc.name} is missing): "
                            'pip install "racerlab[league]"') from None
    if not 0 < args.port < 65536:
        raise RacerlabError(f"--port must be within 1-65535, got {args.port}")
    serve(args.dir, args.db, host=args.host, port=args.port, workers=args.workers, tls_cert=args.tls_cert,
          tls_key=args.tls_key, public_url=args.public_url, ray=args.ray, ray_workers=args.ray_workers)
    return 0


# ---- login ----------------------------------------------------------------------------------------------------
def _login(cmds) -> None:
    p = cmds.add_parser("login", help="log in to a league server (an invite or your password)",
                        description="Log in to the league server at URL: accept an invite (--invite CODE: you "
                                    "choose your password) or log in as --alias. The API token is kept in your "
                                    "config folder (~/.config/racerlab/league.json, mode 0600); the password "
                                    "is not stored.")
    p.add_argument("url", metavar="URL", help="the server's address, e.g. https://league.example.org")
    who = p.add_mutually_exclusive_group(required=True)
    who.add_argument("--invite", metavar="CODE", help="the invite code you were sent")
    who.add_argument("--alias", metavar="ALIAS", help="your alias, for an account you have")
    p.add_argument("--password-file", type=Path, metavar="FILE",
                   help="read the password from FILE's first line ('-': standard input) instead of asking")
    p.add_argument("--ca-cert", type=Path, metavar="FILE", help="the club's own CA certificate (PEM) for https")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run_login)


def read_password(path: Path | None, confirm: bool) -> str:
    """The password from a file (or stdin for '-'), else asked on the terminal (twice when it is new)."""
    import getpass

    from racerlab.errors import RacerlabError

    if path is not None:
        try:
            text = sys.stdin.readline() if str(path) == "-" else path.read_text()
        except OSError as exc:
            raise RacerlabError(f"{path}: cannot read it ({exc.strerror})") from None
        return text.splitlines()[0] if text.strip() else ""
    if not sys.stdin.isatty():
        raise RacerlabError("no terminal to ask the password on; give --password-file FILE ('-' reads stdin)")
    first = getpass.getpass("choose a password (10 characters or more): " if confirm else "password: ")
    if confirm and getpass.getpass("the same password again: ") != first:
        raise RacerlabError("the two passwords differ; run the command again")
    return first


def run_login(args) -> int:
    from racerlab.league.client import login

    password = read_password(args.password_file, confirm=bool(args.invite))
    done = login(args.url, invite=args.invite, alias=args.alias, password=password,
                 ca_cert=str(args.ca_cert) if args.ca_cert else None)
    if args.json:
        print(json.dumps(done, indent=2))
    else:
        print(f"logged in to {done['server']} as {done['alias']} ({done['role']}); the API token is kept in "
              f"{done['config']} (readable by you only)")
    return 0


# ---- submit ---------------------------------------------------------------------------------------------------
def _submit(cmds) -> None:
    p = cmds.add_parser("submit", help="enter a model in a race on a league server",
                        description="Upload MODEL to RACE: a racerlab model folder (packed here: its chosen "
                                    "checkpoint and what describes the model; the reward function stays here), or "
                                    "an archive or folder of an AWS model (console, DRoA or DRfC export, the car's "
                                    "archive). The same model again gets its earlier result: it always scores "
                                    "the same.")
    p.add_argument("model", type=Path, metavar="MODEL", help="a model folder or a .tar.gz / .zip")
    p.add_argument("race", metavar="RACE")
    p.add_argument("--checkpoint", default="best", help="best (default, as AWS), last or an iteration number")
    p.add_argument("--name", default="", help="the name shown for it (default: the folder's or archive's)")
    p.add_argument("--wait", action="store_true", help="follow it until it has a result")
    p.add_argument("--json", action="store_true")
    _url_flag(p)
    p.set_defaults(func=run_submit)


def submission_line(s: dict) -> str:
    """One line of a submission: its race and number, status and why (or its place in the queue)."""
    if s["status"] == "queued":
        eta = "waiting for a worker" if s.get("eta_s") is None else f"ETA about {round(s['eta_s'])} s"
        why = f"#{s['position']} in the queue, {eta}"
    else:
        why = s.get("reason") or ""
    score = f" {s['score_ms'] / 1000:.3f} s" if s.get("score_ms") is not None else ""
    return (f"{s['race']} #{s['number']} (id {s['id']}, {s['model_name']}, model {s['model_hash'][:12]}): "
            f"{s['status_text']}{score}{': ' + why if why else ''}")


def run_submit(args) -> int:
    from racerlab.league.client import Client

    client = Client.stored(args.url)
    sub = client.submit(args.model, args.race, args.checkpoint, args.name)
    if not args.json:
        print(sub["note"] or submission_line(sub))
    if args.wait:
        sub = follow(client, sub, quiet=args.json)
    if args.json:
        print(json.dumps(sub, indent=2))
    return 1 if sub["status"] in ("refused", "failed") else 0


def follow(client, sub: dict, quiet: bool = False, poll_s: float = 1.0) -> dict:
    """Poll a submission until it is final, printing each change of status."""
    import time

    from racerlab.league.views import FINAL

    shown = (sub["status"], sub.get("position"))
    while sub["status"] not in FINAL:
        time.sleep(poll_s)
        sub = client.submission(sub["id"])
        now = (sub["status"], sub.get("position"))
        if now != shown and not quiet:
            print(submission_line(sub), flush=True)
        shown = now
    return sub
