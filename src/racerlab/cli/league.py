"""`racerlab league ...`: run a club's virtual races from the command line (see racerlab.league, docs/league.md).

The web server and the commands that talk to it over HTTP: serve (the pages, the API and local evaluation
workers), login (an invite or a password; the API token is stored in the user's config folder), submit,
status and standings (with the stored login).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("league", help="a race server for many racers: races, submissions, standings",
                       description="Run virtual races for many racers: a store of races and racers, a queue of "
                                   "submissions evaluated by racerlab's race rules, standings. See docs/league.md.")
    cmds = p.add_subparsers(dest="league_command", metavar="COMMAND")
    _serve(cmds)
    _login(cmds)
    _submit(cmds)
    _status(cmds)
    _standings(cmds)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


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
          tls_key=args.tls_key, public_url=args.public_url)
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


# ---- status and standings over HTTP ---------------------------------------------------------------------------
def _status(cmds) -> None:
    p = cmds.add_parser("status", help="your submissions on a league server and what became of them")
    p.add_argument("race", nargs="?", metavar="RACE", help="only this race")
    p.add_argument("--json", action="store_true")
    _url_flag(p)
    p.set_defaults(func=run_status)


def run_status(args) -> int:
    from racerlab.league.client import Client

    subs = Client.stored(args.url).submissions(args.race)
    if args.json:
        print(json.dumps({"submissions": subs}, indent=2))
    else:
        print("\n".join(submission_line(s) for s in subs) or "no submissions yet")
    return 0


def _standings(cmds) -> None:
    p = cmds.add_parser("standings", help="a race's standings from a league server: a table, JSON or CSV")
    p.add_argument("race", metavar="RACE")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--json", action="store_true")
    fmt.add_argument("--csv", action="store_true")
    p.add_argument("-o", "--output", type=Path, help="write to this file instead of printing")
    _url_flag(p)
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


def write_out(text: str, output: Path | None) -> None:
    from racerlab.logs import atomic_write_text

    if output:
        atomic_write_text(output, text)
        print(f"wrote {output}")
    else:
        sys.stdout.write(text)


def run_standings(args) -> int:
    from racerlab.league.client import Client

    client = Client.stored(args.url)
    if args.csv:
        text = client.standings_csv(args.race)
    else:
        st = client.standings(args.race)
        text = json.dumps(st, indent=2) + "\n" if args.json else standings_table(st) + "\n"
    write_out(text, args.output)
    return 0
