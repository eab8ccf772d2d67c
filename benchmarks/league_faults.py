"""League under kill -9: a race of N submissions on a real `racerlab league serve --workers W` while --kills
SIGKILLs land at random moments, half on an evaluation worker, half on the server itself (restarted on the same
port at once, as a service manager would); then every submission's result against an undisturbed run's.

The models: benchmarks/league_web.py's (a features model trained here, N distinct perturbations of it, packed
once; reused with --keep). The undisturbed run: the same N archives submitted through the service to a league with
the same race, evaluated by W local workers, nobody killed. The disturbed run: N racers upload over HTTP to the server
without workers (an upload cut off is sent again, as `racerlab league submit` would be: an identical model is never
entered twice), then the server runs with its W workers and the kills land while the queue is worked, each 0.5 to
--max-gap seconds after the server and its workers are up again; a submission that ran out of attempts ("failed")
is submitted again by its racer once the kills are over (a retry clears it). (Kills during the uploads themselves
starve them: each restarted server's first conversion starts its converter, torch and all, which takes longer than
the gap between kills here.)

Prints one JSON line: the kills (of a worker, of the server; how many found an evaluation under way), the uploads
sent again, the submissions that failed and were cleared by a retry, and the check: per model, the disturbed
result against the undisturbed one (status, score, every lap's figures bit for bit: `identical`, `different`),
`lost` (a model with no submission), `doubled` (a model entered twice), submissions without exactly one result in
the audit log, and SQLite's integrity check; the machine's load before and after.

    python benchmarks/league_faults.py [--submissions 50] [--kills 40] [--workers 2] [--max-gap 3] [--seed 0]
                                       [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from league_throughput import emit, loadavg, note  # noqa: E402
from league_web import FINAL, PASSWORD, RACE, TRACK, archives, free_port, stored, work_root  # noqa: E402

RACE_OPTIONS = {"track": TRACK, "laps": 1, "time_cap_s": 60, "video": False, "max_submissions": 2, "seed": 7}


# ---- the leagues ---------------------------------------------------------------------------------------------
def new_league(root: Path, name: str, racers: int) -> tuple[Path, list[str]]:
    """A fresh league with the race and one racer per submission; (folder, each racer's API token)."""
    from racerlab.league import League

    folder = root / name
    shutil.rmtree(folder, ignore_errors=True)
    league, _ = League.create(folder, password=PASSWORD)
    admin = league.local_admin()
    league.create_race(admin, RACE, dict(RACE_OPTIONS))
    tokens = []
    for r in range(racers):
        actor = league.accept_invite(league.invite(admin, f"racer{r:03d}").code, PASSWORD)
        tokens.append(league.issue_token(actor, "api", label="bench").token)
    league.close()
    return folder, tokens


def results(folder: Path) -> dict[tuple[str, str], list]:
    """(racer, model hash) -> [(status, score, laps) of each of its submissions]."""
    from racerlab.league import League

    league = League.open(folder)
    try:
        admin, out = league.local_admin(), {}
        for sub in league.submissions(admin, RACE, everyone=True):
            full = league.submission(admin, sub.id)
            out.setdefault((full.alias, full.model_hash), []).append((full.status, full.score_ms, full.laps))
        return out
    finally:
        league.close()


def drain(folder: Path, timeout_s: float, alive=None) -> None:
    from racerlab.league import League

    league, end = League.open(folder), time.monotonic() + timeout_s
    try:
        admin = league.local_admin()
        while time.monotonic() < end:
            q = league.queue(admin)
            if q.queued == 0 and q.evaluating == 0:
                return
            if alive is not None:
                alive()
            time.sleep(2.0)
        raise SystemExit(f"league_faults: the queue did not drain within {timeout_s:g} s")
    finally:
        league.close()


def undisturbed(root: Path, models: list[Path], workers: int, timeout_s: float) -> dict[str, list]:
    from racerlab.league import League, start_workers

    folder, _ = new_league(root, "undisturbed", 1)
    league = League.open(folder)
    admin = league.local_admin()
    league.update_race(admin, RACE, max_submissions=len(models))
    for path in models:
        league.submit(admin, RACE, path)
    league.close()
    pool = start_workers(folder, workers=workers, poll_s=0.2)
    try:
        drain(folder, timeout_s)
    finally:
        pool.stop()
    return results(folder)


# ---- the disturbed run ---------------------------------------------------------------------------------------
class Server:
    """`racerlab league serve DIR --workers W` on a fixed loopback port, killed and started again."""

    def __init__(self, folder: Path, workers: int):
        self.folder, self.workers, self.port = folder, workers, free_port()
        self.url, self.proc = f"http://127.0.0.1:{self.port}", None

    def start(self) -> None:
        import httpx

        self.proc = subprocess.Popen([sys.executable, "-m", "racerlab", "league", "serve", str(self.folder),
                                      "--port", str(self.port), "--workers", str(self.workers)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        end = time.monotonic() + 120
        while time.monotonic() < end:
            try:
                httpx.get(f"{self.url}/api/health", timeout=5)
                return
            except httpx.HTTPError:
                time.sleep(0.2)
        raise SystemExit("league_faults: the server did not start")

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(30)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(120)


def live_workers(folder: Path, server_pid: int) -> list[tuple[int, str]]:
    """(pid, state) of the server's workers that are running now."""
    from racerlab.league import League
    from racerlab.league.tables import Worker

    league = League.open(folder)
    try:
        with league.store.read() as s:
            rows = [(w.pid, w.state) for w in s.query(Worker).filter(Worker.state != "stopped")]
    finally:
        league.close()
    return [(pid, state) for pid, state in rows if _parent(pid) == server_pid]


def _parent(pid: int) -> int | None:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return None


def evaluating(folder: Path) -> int:
    from racerlab.league import League

    league = League.open(folder)
    try:
        return league.queue(league.local_admin()).evaluating
    finally:
        league.close()


def upload(server: Server, token: str, path: Path, tally: dict) -> int:
    """Send one model until the server answers it (201, or 200 for the same model again); its submission id."""
    import httpx

    while True:
        try:
            r = httpx.post(f"{server.url}/api/races/{RACE}/submissions", timeout=120,
                           headers={"Authorization": f"Bearer {token}"},
                           files={"model": (path.name, path.read_bytes(), "application/gzip")})
            if r.status_code in (200, 201):
                return r.json()["id"]
            if r.status_code < 500:
                raise SystemExit(f"league_faults: {path.name}: {r.status_code} {r.text}")
        except httpx.HTTPError:
            pass
        tally["uploads_sent_again"] += 1
        time.sleep(0.5)


def up(server: Server, folder: Path, timeout_s: float = 300.0) -> list[tuple[int, str]]:
    """Wait until the server's W workers run (a kill lands on a race under way, not on one still starting)."""
    end = time.monotonic() + timeout_s
    while len(pool := live_workers(folder, server.proc.pid)) < server.workers and time.monotonic() < end:
        time.sleep(0.3)
    return pool


def killer(server: Server, folder: Path, kinds: list[str], rng: random.Random, max_gap: float, tally: dict) -> None:
    for kind in kinds:
        up(server, folder)
        time.sleep(rng.uniform(0.5, max_gap))
        busy = evaluating(folder) > 0
        if kind == "server":
            server.kill()
            tally["server_kills"] += 1
            tally["server_kills_mid_evaluation"] += busy
            server.start()
            continue
        pool = live_workers(folder, server.proc.pid)
        if not pool:
            tally["worker_kills_skipped_none_up"] += 1
            continue
        pid, state = rng.choice([w for w in pool if w[1] == "evaluating"] or pool)
        os.kill(pid, signal.SIGKILL)
        tally["worker_kills"] += 1
        tally["worker_kills_mid_evaluation"] += state == "evaluating"


def disturbed(root: Path, models: list[Path], args, rng: random.Random) -> tuple[dict, dict]:
    folder, tokens = new_league(root, "disturbed", len(models))
    tally = {k: 0 for k in ("server_kills", "server_kills_mid_evaluation", "worker_kills",
                            "worker_kills_mid_evaluation", "worker_kills_skipped_none_up", "uploads_sent_again",
                            "failed_then_retried")}
    server = Server(folder, 0)  # the racers' uploads first, with no worker: the whole race is still to run
    server.start()
    ids = {k: upload(server, tokens[k], path, tally) for k, path in enumerate(models)}
    server.stop()
    server.workers = args.workers
    server.start()
    kinds = ["worker"] * (args.kills // 2) + ["server"] * (args.kills - args.kills // 2)
    rng.shuffle(kinds)
    kills = threading.Thread(target=killer, args=(server, folder, kinds, rng, args.max_gap, tally))
    kills.start()
    try:
        kills.join()
        drain(folder, args.timeout)
        failed = [k for k, sid in ids.items() if _status(folder, sid) == "failed"]
        for k in failed:  # a clear "failed": the racer submits the same model again, which queues it again
            upload(server, tokens[k], models[k], tally)
        tally["failed_then_retried"] = len(failed)
        drain(folder, args.timeout)
    finally:
        kills.join()
        server.stop()
    return results(folder), {**tally, "folder": folder}


def _status(folder: Path, sid: int) -> str:
    from racerlab.league import League

    league = League.open(folder)
    try:
        return league.submission(league.local_admin(), sid).status
    finally:
        league.close()


# ---- the check -----------------------------------------------------------------------------------------------
def check(reference: dict, seen: dict, folder: Path, racers: int) -> dict:
    """Each racer's model once, its result the undisturbed one's (by model: two perturbations can be one model);
    each submission one result but the 'failed' ones a retry cleared; the SQLite file sound."""
    from racerlab.league import League

    rows, _results = stored(folder)
    league = League.open(folder)
    try:
        final = {}
        for e in league.audit(league.local_admin(), 0, 100_000):
            if e.action == "submission.result" and e.detail.get("status") != "failed":
                final[e.subject] = final.get(e.subject, 0) + 1
    finally:
        league.close()
    with sqlite3.connect(folder / "league.db") as db:
        integrity = db.execute("PRAGMA integrity_check").fetchone()[0]
        foreign = len(db.execute("PRAGMA foreign_key_check").fetchall())
    by_model = {h: v[0] for (_alias, h), v in reference.items()}
    first = {key: v[0] for key, v in seen.items()}
    return {"racers": racers, "identical": sum(first[k] == by_model.get(k[1]) for k in first),
            "different": sum(first[k] != by_model.get(k[1]) for k in first),
            "not_final": sum(v[0] not in FINAL for v in first.values()),
            "lost": racers - len(seen), "doubled": sum(len(v) > 1 for v in seen.values()),
            "final_results_not_one": sum(final.get(f"submission:{sid}", 0) != 1 for sid in rows),
            "integrity": integrity, "foreign_key_errors": foreign}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--submissions", type=int, default=50)
    p.add_argument("--kills", type=int, default=40, help="half of a worker, half of the server")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--max-gap", type=float, default=3.0, help="most seconds between two kills")
    p.add_argument("--timeout", type=float, default=3600.0, help="seconds at most for a queue to drain")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--keep", help="the folder for the models (reused by later runs) and the two leagues")
    args = p.parse_args()
    root = work_root(args.keep, "league-faults-")
    models = archives(root, args.submissions)
    load_before, t0 = loadavg(), time.perf_counter()
    note(f"the undisturbed run: {len(models)} submissions, {args.workers} workers")
    reference = undisturbed(root, models, args.workers, args.timeout)
    note(f"the disturbed run: {args.kills} kills")
    seen, tally = disturbed(root, models, args, random.Random(args.seed))
    folder = tally.pop("folder")
    emit(benchmark="league_faults", submissions=len(models), workers=args.workers, kills=args.kills,
         max_gap_s=args.max_gap, seed=args.seed, **tally, check=check(reference, seen, folder, len(models)),
         reference_statuses=_count(v[0][0] for v in reference.values()), distinct_models=len(reference),
         seconds=round(time.perf_counter() - t0),
         load_before=load_before, load_after=loadavg())
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0


def _count(values) -> dict:
    out: dict[str, int] = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return out


if __name__ == "__main__":
    sys.exit(main())
