"""League web routes under a crowd: R racers at once on a real `racerlab league serve --workers W`, over HTTP on
the loopback, for --seconds: each racer logs in with their password, keeps the race's page open (its server-sent
events), submits a distinct model at their limit (--limit uploads spread over the run, then one more that must be
refused), and polls the leaderboard and their own submissions' status every --interval seconds.

The models: a features model trained here for two iterations, and R x limit distinct models made from its
checkpoints with their weights perturbed (benchmarks/league_throughput.py's `submission_folders`: clean laps,
slower laps, no lap), packed as .tar.gz once (reused with --keep). Each run makes a fresh league.

After the crowd the workers finish the queue (--drain seconds at most), and the check: every accepted upload (201)
is a submission of its racer with exactly one result (one final status, one `submission.result` in the audit log),
no racer has more than the limit, and there is no submission that no upload was answered with.

Prints one JSON line: per route (login, submit, standings, status) the requests, errors and latency p50 / p95 / p99
(ms), and the standings' and status' again for the requests made once every racer had logged in (100 Argon2id
password checks, 64 MiB each, take the CPU for their first seconds); the streams' events and errors; the uploads
accepted, refused at the limit and wrongly accepted past it; the check's lost, doubled and stray submissions; the
server's CPU seconds and the machine's load before and after (a busy machine is slower). The budget (DESIGN.md,
issue 44): p95 <= 250 ms for the standings and status routes, no errors, 0 lost or doubled submissions with 100
racers.

    python benchmarks/league_web.py [--racers 100] [--seconds 300] [--limit 2] [--interval 1.0] [--workers 2]
                                    [--drain 1800] [--keep DIR]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import socket
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from league_throughput import emit, loadavg, note, proc_cpu, submission_folders  # noqa: E402

RACE = "crowd"
TRACK = "lab_oval"
PASSWORD = "benchmark password"
FINAL = ("ranked", "not_ranked", "no_lap", "refused", "failed")


# ---- the models and the league -------------------------------------------------------------------------------
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


def archives(root: Path, n: int) -> list[Path]:
    """n distinct model archives (.tar.gz), made once into root/archives."""
    out = root / "archives"
    out.mkdir(parents=True, exist_ok=True)
    have = sorted(out.glob("m*.tar.gz"))
    if len(have) >= n:
        return have[:n]
    model, work = base_model(root), root / "folders"
    for k, folder, _level in submission_folders(model, n, work):
        with tarfile.open(out / f"m{k:04d}.tar.gz", "w:gz") as tar:
            tar.add(folder, arcname=folder.name)
        shutil.rmtree(folder)
    return sorted(out.glob("m*.tar.gz"))[:n]


def league_for(root: Path, racers: int, limit: int) -> Path:
    """A fresh league with one open race (limit `limit`) and R racers with the benchmark's password."""
    from racerlab.league import League

    folder = Path(tempfile.mkdtemp(prefix="club-", dir=root))
    folder.rmdir()
    league, _ = League.create(folder, password=PASSWORD)
    admin = league.local_admin()
    league.create_race(admin, RACE, {"track": TRACK, "laps": 1, "time_cap_s": 60, "video": False,
                                     "max_submissions": limit})
    for r in range(racers):
        league.accept_invite(league.invite(admin, f"racer{r:03d}").code, PASSWORD)
    league.close()
    return folder


def work_root(keep: str | None, prefix: str) -> Path:
    """The benchmark's folder (--keep, or a temporary one), with the AWS tracks beside the checkout on the path."""
    shared = Path(__file__).resolve().parents[2] / "shared" / "tracks"
    if shared.is_dir():
        os.environ.setdefault("RACERLAB_TRACK_PATH", str(shared))
    root = Path(keep) if keep else Path(tempfile.mkdtemp(prefix=prefix))
    root.mkdir(parents=True, exist_ok=True)
    return root


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(folder: Path, port: int, workers: int) -> subprocess.Popen:
    import httpx

    proc = subprocess.Popen([sys.executable, "-m", "racerlab", "league", "serve", str(folder), "--port", str(port),
                             "--workers", str(workers)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    proc.stdout.readline()
    end = time.monotonic() + 60
    while time.monotonic() < end:
        try:
            httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=5)
            return proc
        except httpx.HTTPError:
            time.sleep(0.2)
    raise SystemExit("league_web: the server did not start")


# ---- the crowd -----------------------------------------------------------------------------------------------
class Tally:
    """What the crowd saw: latencies per route, errors, the uploads' answers."""

    def __init__(self):
        self.ms: dict[str, list[float]] = {r: [] for r in ("login", "submit", "standings", "status")}
        self.errors = {r: 0 for r in self.ms}
        self.at = {r: [] for r in self.ms}  # when each request started (perf_counter)
        self.accepted: dict[str, list[int]] = {}
        self.refused_at_limit = self.past_limit = self.events = self.stream_errors = 0

    async def ask(self, route: str, call, ok=(200,)):
        import httpx

        t0 = time.perf_counter()
        try:
            r = await call
        except httpx.HTTPError:
            r = None
        self.ms[route].append((time.perf_counter() - t0) * 1000)
        self.at[route].append(t0)
        if r is None or r.status_code not in ok:
            self.errors[route] += 1
        return r


async def watch(http, tally: Tally) -> None:
    """The race's page: its event stream, open until the racer leaves."""
    import httpx

    try:
        async with http.stream("GET", f"/api/races/{RACE}/events", timeout=None) as r:
            async for line in r.aiter_lines():
                tally.events += line.startswith("event: board")
    except httpx.HTTPError:
        tally.stream_errors += 1


async def upload(http, tally: Tally, alias: str, archive: Path, past_limit: bool) -> None:
    """One upload: a fresh model (201 expected), or one past the limit (409 expected)."""
    files = {"model": (archive.name, archive.read_bytes(), "application/gzip")}
    r = await tally.ask("submit", http.post(f"/api/races/{RACE}/submissions", files=files,
                                            data={"checkpoint": "best"}), ok=(201, 409) if past_limit else (201,))
    if r is None:
        return
    if past_limit:
        tally.refused_at_limit += r.status_code == 409
        tally.past_limit += r.status_code == 201
    if r.status_code == 201:
        tally.accepted.setdefault(alias, []).append(r.json()["id"])


async def uploads(http, tally: Tally, alias: str, mine: list[Path], start: float, end: float) -> None:
    """A racer's uploads, spread over the run, one after the other: their limit, then one more."""
    for k, archive in enumerate([*mine, mine[-1]]):  # the last one again: refused before its body is read
        await asyncio.sleep(max(0.0, start + (k + 0.5) * (end - start) / (len(mine) + 1) - time.monotonic()))
        await upload(http, tally, alias, archive, past_limit=k == len(mine))


async def racer(url: str, alias: str, mine: list[Path], args, tally: Tally, offset: float) -> None:
    import httpx

    await asyncio.sleep(offset)  # racers do not all arrive in the same instant
    async with httpx.AsyncClient(base_url=url, timeout=300) as anon:
        r = await tally.ask("login", anon.post("/api/login", json={"alias": alias, "password": PASSWORD}))
    if r is None or r.status_code != 200:
        return
    headers = {"Authorization": f"Bearer {r.json()['token']}"}
    async with httpx.AsyncClient(base_url=url, headers=headers, timeout=300) as page, \
            httpx.AsyncClient(base_url=url, headers=headers, timeout=300) as http:
        stream = asyncio.create_task(watch(page, tally))
        start, end = time.monotonic(), time.monotonic() + args.seconds - offset
        sending = asyncio.create_task(uploads(http, tally, alias, mine, start, end))
        while time.monotonic() < end:
            cycle = time.monotonic()
            await tally.ask("standings", http.get(f"/api/races/{RACE}/standings"))
            await tally.ask("status", http.get("/api/submissions", params={"race": RACE}))
            await asyncio.sleep(max(0.0, args.interval - (time.monotonic() - cycle)))
        await sending  # an upload still under way finishes (it is part of the load)
        stream.cancel()
        await asyncio.gather(stream, return_exceptions=True)


async def crowd(url: str, models: list[Path], args) -> Tally:
    tally = Tally()
    per = args.limit
    await asyncio.gather(*(racer(url, f"racer{r:03d}", models[r * per:(r + 1) * per], args, tally,
                                 min(10.0, args.seconds / 10) * r / args.racers) for r in range(args.racers)))
    return tally


# ---- the check -----------------------------------------------------------------------------------------------
def workers_up(folder: Path, workers: int, timeout_s: float = 180.0) -> None:
    """Wait until the server's workers have started (their imports would otherwise weigh on the first requests)."""
    from racerlab.league import League

    league, end = League.open(folder), time.monotonic() + timeout_s
    try:
        while league.queue(league.local_admin()).workers < workers:
            if time.monotonic() > end:
                raise SystemExit(f"league_web: the server's {workers} workers did not start within {timeout_s:g} s")
            time.sleep(1.0)
    finally:
        league.close()


def drain(folder: Path, timeout_s: float) -> float:
    """Wait until nothing is queued or under evaluation; the seconds it took."""
    from racerlab.league import League

    league, t0 = League.open(folder), time.monotonic()
    try:
        admin = league.local_admin()
        while time.monotonic() - t0 < timeout_s:
            q = league.queue(admin)
            if q.queued == 0 and q.evaluating == 0:
                return time.monotonic() - t0
            note(f"{q.queued} queued, {q.evaluating} under evaluation")
            time.sleep(5.0)
        raise SystemExit(f"league_web: the queue did not drain within {timeout_s:g} s")
    finally:
        league.close()


def stored(folder: Path) -> tuple[dict[int, tuple[str, str]], dict[int, int]]:
    """What the store holds: {submission id: (alias, status)}, {submission id: its `submission.result` audit rows}."""
    from sqlalchemy import func, select

    from racerlab.league import League
    from racerlab.league.tables import AuditEntry, Submission, User

    league = League.open(folder)
    try:
        with league.store.read() as s:
            rows = {sid: (alias, status) for sid, alias, status in s.execute(
                select(Submission.id, User.alias, Submission.status).join(User, User.id == Submission.user_id))}
            results = dict(s.execute(select(AuditEntry.subject, func.count()).where(
                AuditEntry.action == "submission.result").group_by(AuditEntry.subject)).all())
    finally:
        league.close()
    return rows, {sid: results.get(f"submission:{sid}", 0) for sid in rows}


def check(folder: Path, tally: Tally, limit: int) -> dict:
    """Every accepted upload one submission with one result; nothing doubled, nothing stray."""
    rows, results = stored(folder)
    accepted = {sid: alias for alias, ids in tally.accepted.items() for sid in ids}
    statuses: dict[str, int] = {}
    for _alias, status in rows.values():
        statuses[status] = statuses.get(status, 0) + 1
    return {"accepted": len(accepted), "stored": len(rows), "statuses": statuses,
            "lost": sum(sid not in rows or rows[sid][0] != alias for sid, alias in accepted.items()),
            "stray": sum(sid not in accepted for sid in rows),
            "not_final": sum(status not in FINAL for _a, status in rows.values()),
            "doubled_results": sum(n != 1 for n in results.values()),
            "over_limit_racers": sum(len(ids) > limit for ids in tally.accepted.values())}


def ms(values) -> dict:
    a = np.asarray(values, dtype=float)
    return {f"p{q}": round(float(np.percentile(a, q)), 1) for q in (50, 95, 99)} if len(a) else {}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--racers", type=int, default=100)
    p.add_argument("--seconds", type=float, default=300.0)
    p.add_argument("--limit", type=int, default=2, help="the race's submission limit (each racer uses it all)")
    p.add_argument("--interval", type=float, default=1.0, help="seconds between a racer's polls")
    p.add_argument("--workers", type=int, default=2, help="the server's local evaluation workers")
    p.add_argument("--drain", type=float, default=1800.0, help="seconds at most for the workers to finish after")
    p.add_argument("--keep", help="the folder for the models and leagues (the models are reused by later runs)")
    args = p.parse_args()
    root = work_root(args.keep, "league-web-bench-")
    note(f"preparing {args.racers * args.limit} model archives and {args.racers} racers in {root}")
    models = archives(root, args.racers * args.limit)
    folder = league_for(root, args.racers, args.limit)
    port = free_port()
    proc = serve(folder, port, args.workers)
    workers_up(folder, args.workers)
    load_before = loadavg()
    try:
        cpu0, t0, mine0 = proc_cpu(proc.pid), time.perf_counter(), time.process_time()
        tally = asyncio.run(crowd(f"http://127.0.0.1:{port}", models, args))
        wall, cpu = time.perf_counter() - t0, proc_cpu(proc.pid) - cpu0
        client_cpu = time.process_time() - mine0
        drain_s = drain(folder, args.drain)
    finally:
        proc.terminate()
        proc.wait(60)
        proc.stdout.close()
    routes = {r: {"requests": len(v), "errors": tally.errors[r], **ms(v)} for r, v in tally.ms.items()}
    logged_in = max(t + d / 1000 for t, d in zip(tally.at["login"], tally.ms["login"], strict=True))
    steady = {r: {"requests": len(late), **ms(late)} for r in ("standings", "status") if (late := [
        d for t, d in zip(tally.at[r], tally.ms[r], strict=True) if t > logged_in])}
    emit(benchmark="league_web", racers=args.racers, seconds=args.seconds, limit=args.limit,
         interval_s=args.interval, workers=args.workers, cores=os.cpu_count(), routes=routes,
         after_last_login=steady, logins_took_s=round(logged_in - min(tally.at["login"]), 1),
         requests_per_s=round(sum(len(v) for v in tally.ms.values()) / wall, 1), board_events=tally.events,
         stream_errors=tally.stream_errors, refused_at_limit=tally.refused_at_limit,
         accepted_past_limit=tally.past_limit, check=check(folder, tally, args.limit), drain_s=round(drain_s, 1),
         server_cpu_s=round(cpu, 1), client_cpu_s=round(client_cpu, 1), load_before=load_before,
         load_after=loadavg(), budget_p95_ms=250)
    if args.keep:  # every request's start (s after the first) and latency (ms), to see when the slow ones were
        first = min(min(v) for v in tally.at.values() if v)
        (root / "latency.json").write_text(json.dumps({r: [[round(t - first, 3), round(d, 1)] for t, d in zip(
            tally.at[r], tally.ms[r], strict=True)] for r in tally.ms}))
    else:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
