"""Nothing lost under kill -9: `racerlab train` killed at random moments of its training, restarted each time.

A small features model trains on lab_oval; each round starts `racerlab train MODEL --iterations 1000`, waits
until it has resumed and then a random 0-`--max-wait` seconds (a kill lands anywhere: collection, learning,
a checkpoint or log being written), sends SIGKILL, and checks the folder the way the next run will meet it:

- `lost`: completed iterations that a kill took away (the next run must resume at the newest complete
  checkpoint seen before the kill, never earlier);
- `unreadable`: checkpoints that do not load (weights_only) and metrics.jsonl lines that do not parse;
- `refused`: restarts refused by the training lock a killed trainer left;
- `temp_left`: temporary files left once a final, uninterrupted run has finished.

Prints one JSON object.

    python benchmarks/kill_resume.py [--kills 20] [--max-wait 6] [--seed 0] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from racerlab.model import ModelFolder, init_model

RESUME_RE = re.compile(r"resuming at iteration (\d+)")


def _start(model: Path, iterations: int) -> tuple[subprocess.Popen, list[str], threading.Event]:
    proc = subprocess.Popen([sys.executable, "-m", "racerlab", "train", str(model), "--iterations", str(iterations)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    lines: list[str] = []
    started = threading.Event()

    def read():
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            if line.startswith("training "):
                started.set()
        started.set()

    threading.Thread(target=read, daemon=True).start()
    return proc, lines, started


def _complete(folder: ModelFolder) -> int:
    """The newest iteration whose checkpoint is on disk (files appear whole or not at all)."""
    cps = folder.checkpoints()
    return cps[-1].iteration if cps else 0


def _unreadable(folder: ModelFolder) -> list[str]:
    bad = []
    for c in folder.checkpoints():
        try:
            folder.load_checkpoint(c)
        except Exception as exc:  # noqa: BLE001 - counted, not raised
            bad.append(f"{c.name}: {exc}")
    metrics = folder.path / "metrics" / "metrics.jsonl"
    if metrics.is_file():
        for n, line in enumerate(metrics.read_text().splitlines(), 1):
            try:
                json.loads(line)
            except json.JSONDecodeError:
                bad.append(f"metrics.jsonl line {n}")
    return bad


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=20)
    ap.add_argument("--max-wait", type=float, default=6.0, help="seconds after the resume at most (default 6)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, help="keep the model folder here")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    work = Path(tempfile.mkdtemp(prefix="racerlab-killbench-"))
    model = init_model(work / "m", track="lab_oval", num_cars=8)
    folder = ModelFolder(model.path)
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    rounds, lost, refused, unreadable = [], 0, 0, []
    for k in range(args.kills):
        seen = _complete(folder)
        proc, lines, started = _start(model.path, 1000)
        started.wait(300)
        resumed = next((int(m.group(1)) for ln in lines if (m := RESUME_RE.search(ln))), 0)
        if proc.poll() is not None and "being trained by process" in "\n".join(lines):
            refused += 1
        if resumed < seen:
            lost += seen - resumed
        wait = rng.uniform(0, args.max_wait)
        time.sleep(wait)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        after = _complete(folder)
        bad = _unreadable(folder)
        unreadable += bad
        rounds.append({"kill": k + 1, "resumed_at": resumed, "complete_before": seen, "killed_after_s": round(wait, 2),
                       "complete_after": after, "unreadable": len(bad)})
        print(json.dumps(rounds[-1]), file=sys.stderr, flush=True)
    seen = _complete(folder)
    proc, lines, started = _start(model.path, 1)  # a last run, left to finish: it must resume where the kills left
    proc.wait(600)
    resumed = next((int(m.group(1)) for ln in lines if (m := RESUME_RE.search(ln))), 0)
    lost += max(seen - resumed, 0)
    temp_left = [str(p.relative_to(model.path)) for p in model.path.rglob("*") if ".tmp-" in p.name]
    result = {
        "benchmark": "kill_resume", "kills": args.kills, "lost_iterations": lost, "refused_restarts": refused,
        "unreadable_files": len(unreadable), "temp_files_left": len(temp_left), "final_run_rc": proc.returncode,
        "iterations_completed": _complete(folder), "lock_left": folder.lock_path.exists(),
        "kills_during_iteration": sum(r["complete_after"] == r["resumed_at"] for r in rounds),
        "seconds": round(time.perf_counter() - t0, 1), "load_before": [round(x, 2) for x in load_before],
        "load_after": [round(x, 2) for x in os.getloadavg()], "details": unreadable[:5] + temp_left[:5]}
    print(json.dumps(result))
    if args.keep:
        shutil.copytree(model.path, args.keep, dirs_exist_ok=True)
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
