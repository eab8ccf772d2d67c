"""League web routes under a crowd: R racers at once on a real `racerlab league serve`, each with the race's page
open (its server-sent events) and polling the leaderboard and their own submissions' status over the HTTP API.

The league is real: a features model trained here for two iterations, R distinct models made from it (its
checkpoints with their weights perturbed, as benchmarks/league_throughput.py does: clean laps, slower laps, no lap),
submitted through the service and evaluated by two local workers, so the standings hold R racers' stored results.
Then the server runs alone (no workers) in its own process and R clients, each with its own API token, open the
board's event stream and, every --interval seconds for --seconds, ask `GET /api/races/NAME/standings` and `GET
/api/submissions?race=NAME`.

Prints one JSON line: requests, errors, latency p50 / p95 / p99 per route (ms), requests per second served, the
events received, the server's CPU seconds, and the machine's load before and after (a busy machine is slower).
The budget (DESIGN.md): p95 <= 250 ms and no errors with 100 racers at once.

    python benchmarks/league_web.py [--racers 100] [--seconds 30] [--interval 1.0] [--keep DIR]
"""

from __future__ import annotations

import argparse
import asyncio
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from league_throughput import emit, loadavg, note, proc_cpu, submission_folders  # noqa: E402

RACE = "crowd"
TRACK = "lab_oval"
PASSWORD = "benchmark password"


# ---- the league ----------------------------------------------------------------------------------------------
def base_model(root: Path) -> Path:
    """A features model trained here for two iterations (two checkpoints to perturb)."""
    base = root / "base"
    if not (base / "checkpoints").is_dir() or len(list((base / "checkpoints").glob("*.pt"))) < 2:
        shutil.rmtree(base, ignore_errors=True)
        cmd = [sys.executable, "-m", "racerlab"]
        subprocess.run([*cmd, "init", str(base), "--sensor", "features", "--track", TRACK], check=True,
                       stdout=subprocess.DEVNULL)
        subprocess.run([*cmd, "train", str(base), "--iterations", "2"], check=True, stdout=subprocess.DEVNULL)
    return base


def prepare(root: Path, racers: int) -> Path:
    """A league in root/club with one race and one evaluated submission per racer (reused when it is there)."""
    from racerlab.league import League, start_workers

    folder = root / "club"
    if (folder / "league.db").is_file():
        return folder
    model = base_model(root)
    league, _ = League.create(folder, password=PASSWORD)
    admin = league.local_admin()
    league.create_race(admin, RACE, {"track": TRACK, "laps": 2, "time_cap_s": 60, "video": False})
    people = [league.accept_invite(league.invite(admin, f"racer{r:03d}").code, PASSWORD) for r in range(racers)]
    pool = start_workers(folder, workers=2, poll_s=0.2)
    try:
        for k, path, _level in submission_folders(model, racers, root / "uploads"):
            league.submit(people[k], RACE, path)
            shutil.rmtree(path)
        while league.queue(admin).queued or league.queue(admin).evaluating:
            time.sleep(2.0)
    finally:
        pool.stop()
    league.close()
    return folder


def tokens(folder: Path, racers: int) -> list[str]:
    """An API token for each racer (as `racerlab league login` gets one)."""
    from racerlab.league import Actor, League

    league = League.open(folder)
    try:
        by_alias = {u.alias: u for u in league.users(league.local_admin())}
        return [league.issue_token(Actor(u.id, u.alias, u.role), "api", label="bench").token
                for u in (by_alias[f"racer{r:03d}"] for r in range(racers))]
    finally:
        league.close()


# ---- the crowd -----------------------------------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(folder: Path, port: int) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "racerlab", "league", "serve", str(folder), "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    proc.stdout.readline()
    import httpx

    end = time.monotonic() + 60
    while time.monotonic() < end:
        try:
            httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=5)
            return proc
        except httpx.HTTPError:
            time.sleep(0.2)
    raise SystemExit("league_web: the server did not start")


async def racer(http, seconds: float, interval: float, out: dict, offset: float) -> None:
    """One racer's polls: the standings and their own submissions' status, every `interval` seconds."""
    import httpx

    routes = {"standings": f"/api/races/{RACE}/standings", "status": f"/api/submissions?race={RACE}"}
    await asyncio.sleep(offset)  # racers do not all poll in the same instant
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        cycle = time.monotonic()
        for name, path in routes.items():
            t0 = time.perf_counter()
            try:
                ok = (await http.get(path)).status_code == 200
            except httpx.HTTPError:
                ok = False
            out[name].append((time.perf_counter() - t0) * 1000)
            out["errors"] += not ok
        await asyncio.sleep(max(0.0, interval - (time.monotonic() - cycle)))


async def board(http, out: dict) -> None:
    """The race's page: its event stream, open until the polls end."""
    import httpx

    try:
        async with http.stream("GET", f"/api/races/{RACE}/events", timeout=None) as r:
            async for line in r.aiter_lines():
                out["events"] += line.startswith("event: board")
    except httpx.HTTPError:
        out["stream_errors"] += 1


async def crowd(url: str, toks: list[str], seconds: float, interval: float) -> dict:
    import httpx

    out = {"standings": [], "status": [], "errors": 0, "events": 0, "stream_errors": 0}
    tls = httpx.create_ssl_context()  # one for all (each client would build its own: 0.4 s of the client's CPU)
    pages = [httpx.AsyncClient(base_url=url, headers={"Authorization": f"Bearer {t}"}, timeout=30, verify=tls)
             for t in toks]
    polls = [httpx.AsyncClient(base_url=url, headers={"Authorization": f"Bearer {t}"}, timeout=30, verify=tls)
             for t in toks]
    boards = [asyncio.create_task(board(http, out)) for http in pages]
    await asyncio.sleep(2.0)  # the pages open first, as on race day
    t0 = time.perf_counter()
    await asyncio.gather(*(racer(http, seconds, interval, out, interval * k / len(toks))
                           for k, http in enumerate(polls)))
    out["wall_s"] = time.perf_counter() - t0
    for task in boards:  # the pages close when the polls end
        task.cancel()
    await asyncio.gather(*boards, return_exceptions=True)
    for http in pages + polls:
        await http.aclose()
    return out


def ms(values) -> dict:
    a = np.asarray(values, dtype=float)
    return {f"p{q}": round(float(np.percentile(a, q)), 1) for q in (50, 95, 99)} if len(a) else {}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--racers", type=int, default=100)
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--interval", type=float, default=1.0, help="seconds between a racer's polls")
    p.add_argument("--keep", help="the folder for the league and its model (reused by later runs)")
    args = p.parse_args()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="league-web-bench-"))
    root.mkdir(parents=True, exist_ok=True)
    note(f"preparing {args.racers} racers' results in {root} (reused with --keep)")
    folder = prepare(root, args.racers)
    toks = tokens(folder, args.racers)
    port = free_port()
    proc = serve(folder, port)
    load_before = loadavg()
    try:
        cpu0 = proc_cpu(proc.pid)
        out = asyncio.run(crowd(f"http://127.0.0.1:{port}", toks, args.seconds, args.interval))
        wall, cpu = out["wall_s"], proc_cpu(proc.pid) - cpu0
    finally:
        proc.terminate()
        proc.wait(60)
        proc.stdout.close()
    n = len(out["standings"]) + len(out["status"])
    emit(benchmark="league_web", racers=args.racers, seconds=args.seconds, interval_s=args.interval, requests=n,
         errors=out["errors"], stream_errors=out["stream_errors"], requests_per_s=round(n / wall, 1),
         standings_ms=ms(out["standings"]), status_ms=ms(out["status"]), board_events=out["events"],
         server_cpu_s=round(cpu, 1), load_before=load_before, load_after=loadavg(), budget_p95_ms=250)
    return 0


if __name__ == "__main__":
    sys.exit(main())
