"""League throughput: N camera submissions of mixed quality (3 laps, reInvent2019_track, with video) through the
whole server path on this machine: submit (conversion in the locked-down child, the insert's transaction), the
durable queue, W local workers, evaluation with its MP4, the result stored.

Prints one JSON line: submissions per hour, CPU seconds per submission (every process of the league: workers with
their ffmpeg, the conversion server with its children, the submitting process), evaluation CPU seconds per
submission as the workers measured them, the wait in the queue and the turnaround (submit to result) at p50 /
p95, the outcomes, and DRoA's cost beside them (one ml.c7i.4xlarge, 16 vCPU, for 5-20 minutes per submission).
The machine's load before and after is in the line too: figures taken on a busy machine are slower.

The models: `--model DIR` (a trained camera model folder; default: one trained here first with `racerlab train
--minutes --train-minutes` into --cache, reused by later runs). Submission k races checkpoint k mod C of that folder
with its policy's weights perturbed by noise of k's level (0, 0.3 %, 1 %, 3 % of each tensor's spread): a mix of
clean laps, slower laps with off-tracks and cars that never finish a lap, each a distinct model.

    python benchmarks/league_throughput.py [--submissions 200] [--workers 2] [--racers 40] [--model DIR]
                                           [--arrival burst|steady] [--rate PER_HOUR] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

NOISE_LEVELS = (0.0, 0.003, 0.01, 0.03)
DROA_VCPU, DROA_MINUTES = 16, (5, 20)
TRACK = "reInvent2019_track"


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def note(text: str) -> None:
    print(f"league_throughput: {text}", file=sys.stderr, flush=True)


def loadavg() -> list[float]:
    return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]


# ---- the models ----------------------------------------------------------------------------------------------
def trained_model(args) -> Path:
    """The camera model to race: --model, or one trained once into --cache."""
    if args.model:
        return Path(args.model)
    cam = Path(args.cache) / "camera"
    if not (cam / "checkpoints" / "deepracer_checkpoints.json").is_file() or len(list(
            (cam / "checkpoints").glob("*.pt"))) < 2:
        note(f"training a camera model in {cam} for {args.train_minutes} minutes (once; --model skips this)")
        shutil.rmtree(cam, ignore_errors=True)
        cmd = [sys.executable, "-m", "racerlab"]
        subprocess.run([*cmd, "init", str(cam), "--sensor", "camera", "--track", TRACK, "--max-speed", "3",
                        "--reward", "racing_line", "--best-model-metric", "laptime"], check=True)
        subprocess.run([*cmd, "train", str(cam), "--minutes", str(args.train_minutes)], check=True)
    return cam


def submission_folders(model: Path, n: int, out: Path):
    """Yield (k, folder) of n distinct model folders of mixed quality made from `model`'s checkpoints."""
    import torch

    from racerlab.model import ModelFolder, TrainingState

    src = ModelFolder(model)
    states = [src.load_state(c) for c in src.checkpoints() if c.iteration > 0] or [
        src.load_state(c) for c in src.checkpoints()]
    for k in range(n):
        state = states[k % len(states)]
        level = NOISE_LEVELS[(k // len(states)) % len(NOISE_LEVELS)]
        gen = torch.Generator().manual_seed(1000 + k)
        policy = {}
        for name, t in state.agent["policy"].items():
            noise = torch.randn(t.shape, generator=gen) * float(t.float().std()) * level if t.is_floating_point() \
                and t.numel() > 1 else 0
            policy[name] = (t + noise) if t.is_floating_point() else t
        if level == 0.0:  # a distinct model all the same: one bias moved by a nanosecond of its spread
            first = next(iter(policy))
            policy[first] = policy[first].clone()
            policy[first].view(-1)[0] += 1e-9 * (k + 1)
        folder = ModelFolder(out / f"m{k:04d}")
        folder.path.mkdir(parents=True)
        for p in (src.metadata_path, src.config_path, src.reward_path):
            shutil.copyfile(p, folder.path / p.name)
        agent = {"format": state.agent["format"], "policy": policy}
        info = folder.save_state(TrainingState(agent, state.metadata, iteration=1, train_steps=1))
        folder.update_index(info, 0.0, info, 0.0)
        yield k, folder.path, level


# ---- CPU accounting ------------------------------------------------------------------------------------------
def proc_cpu(pid: int) -> float:
    """utime + stime + cutime + cstime of a process (seconds), 0 when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return sum(int(x) for x in fields[11:15]) / os.sysconf("SC_CLK_TCK")


def self_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def forkserver_pid() -> int | None:
    from multiprocessing import forkserver

    return getattr(forkserver._forkserver, "_forkserver_pid", None)


# ---- the run -------------------------------------------------------------------------------------------------
def percentiles(values) -> dict:
    if not values:
        return {"p50": None, "p95": None}
    a = np.asarray(values, dtype=float)
    return {"p50": round(float(np.percentile(a, 50)), 2), "p95": round(float(np.percentile(a, 95)), 2),
            "mean": round(float(a.mean()), 2)}


def submit_all(league, admin, model, args, work: Path) -> tuple[list[int], float, float]:
    """Submit every model (one racer in turn each); (ids, seconds the submit calls took, their CPU here)."""
    racers = [league.accept_invite(league.invite(admin, f"racer{r:03d}").code, "benchmark password")
              for r in range(args.racers)]
    gap = 3600.0 / args.rate if args.arrival == "steady" else 0.0
    ids, t0, cpu, wall = [], time.perf_counter(), 0.0, 0.0
    for k, folder, _level in submission_folders(model, args.submissions, work / "uploads"):
        if gap:
            time.sleep(max(0.0, t0 + k * gap - time.perf_counter()))
        c0, w0 = self_cpu(), time.perf_counter()  # the submission alone, not the making of its model folder
        ids.append(league.submit(racers[k % len(racers)], "bench", folder).id)
        cpu, wall = cpu + self_cpu() - c0, wall + time.perf_counter() - w0
        shutil.rmtree(folder)
    return ids, wall, cpu


def wait_done(league, admin, ids, timeout_s: float) -> list:
    final = ("ranked", "not_ranked", "no_lap", "refused", "failed")
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        subs = [league.submission(admin, i) for i in ids]
        done = sum(s.status in final for s in subs)
        if done == len(ids):
            return subs
        note(f"{done}/{len(ids)} evaluated")
        time.sleep(10.0)
    raise SystemExit(f"league_throughput: not all evaluated within {timeout_s:g} s")


def run(args) -> dict:
    from racerlab.league import League, start_workers

    model = trained_model(args)
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="league-bench-"))
    league, _ = League.create(root / "club", password="benchmark password")
    admin = league.local_admin()
    league.create_race(admin, "bench", {"track": TRACK, "laps": 3, "timing": "best_lap", "video": True,
                                        "max_submissions": 10_000})
    load_before = loadavg()
    pool = start_workers(league.store.folder, workers=args.workers, poll_s=0.2)
    pids = list(pool.pids.values())
    try:
        ids, submit_s, submit_cpu = submit_all(league, admin, model, args, root)
        subs = wait_done(league, admin, ids, args.timeout)
        cpu_workers = sum(proc_cpu(p) for p in pids)  # before they exit: their CPU, their ffmpeg children's
        fs = forkserver_pid()
        cpu_convert = proc_cpu(fs) if fs else 0.0
    finally:
        pool.stop()
    return summarise(league, admin, subs, args, submit_s, submit_cpu, cpu_workers, cpu_convert, load_before, root)


def summarise(league, admin, subs, args, submit_s, submit_cpu, cpu_workers, cpu_convert, load_before, root) -> dict:
    starts = [s.started_at.timestamp() for s in subs]
    ends = [s.finished_at.timestamp() for s in subs]
    created = [s.created_at.timestamp() for s in subs]
    span = max(ends) - min(created)
    with league.store.read() as s:
        from sqlalchemy import select

        from racerlab.league.tables import Submission

        rows = s.scalars(select(Submission).where(Submission.id.in_([x.id for x in subs]))).all()
        eval_cpu = [r.eval_cpu_seconds for r in rows if r.eval_cpu_seconds is not None]
        eval_wall = [r.eval_seconds for r in rows if r.eval_seconds is not None]
    statuses: dict[str, int] = {}
    for x in subs:
        statuses[x.status] = statuses.get(x.status, 0) + 1
    n = len(subs)
    total_cpu = cpu_workers + cpu_convert + submit_cpu
    best = min((x.score_ms for x in subs if x.score_ms), default=None)
    return {
        "benchmark": "league_throughput", "submissions": n, "workers": args.workers, "cores": os.cpu_count(),
        "track": TRACK, "laps": 3, "video": True, "arrival": args.arrival,
        "submissions_per_hour": round(3600.0 * n / span, 1),
        "cpu_s_per_submission": round(total_cpu / n, 2),
        "cpu_s_parts": {"workers_with_ffmpeg": round(cpu_workers / n, 2), "conversion": round(cpu_convert / n, 2),
                        "submitting": round(submit_cpu / n, 3)},
        "eval_cpu_s": percentiles(eval_cpu), "eval_wall_s": percentiles(eval_wall),
        "wait_s": percentiles([a - c for a, c in zip(starts, created, strict=True)]),
        "turnaround_s": percentiles([e - c for e, c in zip(ends, created, strict=True)]),
        "submit_s_each": round(submit_s / n, 3), "statuses": statuses,
        "best_lap_s": None if best is None else best / 1000,
        "laps_completed": sum(x.laps_completed or 0 for x in subs),
        "droa": {"instance": "ml.c7i.4xlarge", "vcpu": DROA_VCPU, "minutes_per_submission": list(DROA_MINUTES),
                 "vcpu_s_per_submission": [DROA_VCPU * 60 * m for m in DROA_MINUTES]},
        "load_before": load_before, "load_after": loadavg(), "store": str(root) if args.keep else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--submissions", type=int, default=200)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--racers", type=int, default=40)
    ap.add_argument("--model", help="a trained camera model folder (default: trained once into --cache)")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "racerlab-league-bench"))
    ap.add_argument("--train-minutes", type=float, default=15.0)
    ap.add_argument("--arrival", choices=["burst", "steady"], default="burst",
                    help="burst: everything submitted at once (a race opening); steady: --rate per hour")
    ap.add_argument("--rate", type=float, default=600.0, help="submissions per hour with --arrival steady")
    ap.add_argument("--timeout", type=float, default=6 * 3600.0)
    ap.add_argument("--keep", help="build the league in this folder and keep it (default: a temporary one)")
    args = ap.parse_args()
    shared = Path(__file__).resolve().parents[2] / "shared" / "tracks"  # the AWS tracks beside the checkout
    if shared.is_dir():
        os.environ.setdefault("RACERLAB_TRACK_PATH", str(shared))
    emit(**run(args))


if __name__ == "__main__":
    main()
