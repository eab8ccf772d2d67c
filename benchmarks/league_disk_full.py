"""League on a disk that fills during its evaluations: every submission ends with the undisturbed run's result or a
clear "failed" that the racer's retry clears, and the store stays sound.

The models and the undisturbed run are benchmarks/league_faults.py's (N distinct features models, 2 local workers).
The disturbed run puts the whole league, its SQLite database included, on a small tmpfs (mounting it needs root)
and evaluates the same N submissions with W workers while --fills times a file takes all the disk's room for
--hold seconds, each when an evaluation is under way. Submissions that failed are submitted again by their racer
once the disk has room (a failed model entered again is queued again, not counted), until none is left failed.

Prints one JSON line: the fills (and how many found an evaluation under way), the submissions failed for want of
disk and their one-line reason, the retry rounds, and league_faults' check of every result against the undisturbed
run's (status, score, every lap bit for bit), lost and doubled submissions, results per submission and SQLite's
integrity check; the load before and after.

    sudo python benchmarks/league_disk_full.py [--submissions 20] [--fills 10] [--hold 2] [--workers 2] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from league_faults import RACE, check, drain, new_league, results, undisturbed  # noqa: E402
from league_throughput import emit, loadavg, note  # noqa: E402
from league_web import archives, work_root  # noqa: E402


def fill(mnt: Path) -> Path:
    """A file that takes all of the disk's room (allocated, not sparse)."""
    filler = mnt / "filler"
    with open(filler, "wb") as f:
        free = shutil.disk_usage(mnt).free
        try:
            os.posix_fallocate(f.fileno(), 0, free)
        except OSError:  # a few pages short of `free`: take what there is
            os.posix_fallocate(f.fileno(), 0, max(0, free - (256 << 10)))
    return filler


def filler_thread(folder: Path, mnt: Path, fills: int, hold_s: float, rng: random.Random, tally: dict,
                  done: threading.Event) -> None:
    from racerlab.league import League

    league = League.open(folder)
    admin = league.local_admin()
    try:
        while tally["fills"] < fills and not done.is_set():
            if league.queue(admin).evaluating == 0:
                time.sleep(0.1)
                continue
            time.sleep(rng.uniform(0.0, 1.0))
            busy = league.queue(admin).evaluating > 0
            filler = fill(mnt)
            tally["fills"] += 1
            tally["fills_during_evaluation"] += busy
            time.sleep(hold_s)
            filler.unlink()
            time.sleep(rng.uniform(0.5, 2.0))
    finally:
        league.close()


def failed(folder: Path) -> list:
    from racerlab.league import League

    league = League.open(folder)
    try:
        admin = league.local_admin()
        return [league.submission(admin, s.id) for s in league.submissions(admin, RACE, everyone=True)
                if s.status == "failed"]
    finally:
        league.close()


def disturbed(root: Path, models: list[Path], args) -> tuple[dict, dict, Path]:
    from racerlab.league import League, start_workers

    mnt = root / "disk"
    mnt.mkdir(exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={args.size_mib}m", "tmpfs", str(mnt)], check=True)
    folder, _ = new_league(mnt, "disturbed", 1)
    league = League.open(folder)
    admin = league.local_admin()
    league.update_race(admin, RACE, max_submissions=len(models))
    by_hash = {league.submit(admin, RACE, path).model_hash: path for path in models}
    league.close()
    tally = {"fills": 0, "fills_during_evaluation": 0, "failed_for_disk": 0, "failed_other": 0, "reasons": [],
             "retry_rounds": 0}
    done = threading.Event()
    pool = start_workers(folder, workers=args.workers, poll_s=0.2)
    thread = threading.Thread(target=filler_thread, args=(folder, mnt, args.fills, args.hold, random.Random(
        args.seed), tally, done), daemon=True)
    thread.start()
    try:
        while True:
            drain(folder, args.timeout)
            left = failed(folder)
            if left:
                retry(folder, left, by_hash, tally)
                continue
            if not thread.is_alive():
                break
            done.set()  # the queue is empty: no evaluation left for the remaining fills to disturb
            thread.join()
    finally:
        done.set()
        pool.stop()
    seen = results(folder)
    return seen, tally, mnt


def retry(folder: Path, left: list, by_hash: dict, tally: dict) -> None:
    """Each failed submission's racer submits the same model again (it is queued again)."""
    from racerlab.league import League
    from racerlab.league.worker import DISK_FULL_REASON

    tally["retry_rounds"] += 1
    league = League.open(folder)
    try:
        admin = league.local_admin()
        for sub in left:
            key = "failed_for_disk" if sub.reason == DISK_FULL_REASON else "failed_other"
            tally[key] += 1
            if sub.reason not in tally["reasons"]:
                tally["reasons"].append(sub.reason)
            league.submit(admin, RACE, by_hash[sub.model_hash])
    finally:
        league.close()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--submissions", type=int, default=20)
    p.add_argument("--fills", type=int, default=10)
    p.add_argument("--hold", type=float, default=2.0, help="seconds the disk stays full each time")
    p.add_argument("--size-mib", type=int, default=96, help="the tmpfs the league lives on")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--timeout", type=float, default=3600.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--keep", help="the folder for the models (reused by later runs)")
    args = p.parse_args()
    if os.geteuid() != 0:
        raise SystemExit("league_disk_full: mounting the small disk needs root; run it with sudo")
    root = work_root(args.keep, "league-disk-full-")
    models = archives(root, args.submissions)
    load_before, t0 = loadavg(), time.perf_counter()
    note(f"the undisturbed run: {len(models)} submissions, {args.workers} workers")
    reference = undisturbed(root, models, args.workers, args.timeout)
    note(f"the disturbed run: the disk filled {args.fills} times for {args.hold:g} s")
    mnt = None
    try:
        seen, tally, mnt = disturbed(root, models, args)
        report = check(reference, seen, mnt / "disturbed", len(models))
    finally:
        if mnt is not None:
            subprocess.run(["umount", "-l", str(mnt)], check=False)
    emit(benchmark="league_disk_full", submissions=len(models), workers=args.workers, hold_s=args.hold,
         size_mib=args.size_mib, seed=args.seed, **tally, check=report, seconds=round(time.perf_counter() - t0),
         load_before=load_before, load_after=loadavg())
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
