"""Loading a 1 M-row simtrace: racerlab.analysis.load (cold, cold on one thread, cached, after a new
iteration) against deepracer-utils on the same DRfC multi-worker folder. One JSON line per measurement.

Budget (DESIGN.md): cold load of 1 M rows <= 1.5 s; deepracer-utils: 6.1 s on this machine's reference run.

    python benchmarks/analysis_speed.py [--rows 1000000] [--workers 3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from racerlab.analysis import load
from racerlab.logs.layout import training_simtrace_path
from racerlab.logs.simtrace import SimtraceWriter, format_rows
from racerlab.logs.synthetic import episode_columns, write_training_folder

ITERATIONS = 400
MEAN_STEPS = 120


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def timed(fn, repeat: int = 1):
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def bench_writer() -> None:
    rng = np.random.default_rng(1)
    cols = episode_columns(np.arange(800), rng.integers(30, 210, 800), rng)
    n = len(cols["episode"])
    dt, _ = timed(lambda: format_rows(cols), repeat=3)
    emit(bench="simtrace_format", rows=n, seconds=round(dt, 4), rows_per_s=round(n / dt))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--workers", type=int, default=3)
    ap.add_argument("--keep", help="generate into this folder and keep it")
    args = ap.parse_args()

    bench_writer()
    tmp = Path(tempfile.mkdtemp(prefix="racerlab-bench-"))
    folder = Path(args.keep) if args.keep else tmp / "model"
    cache = tmp / "cache"
    per_worker = max(1, round(args.rows / (args.workers * ITERATIONS * MEAN_STEPS)))
    try:
        dt, rows = timed(lambda: write_training_folder(folder, ITERATIONS, per_worker, args.workers, MEAN_STEPS))
        size = sum(p.stat().st_size for p in folder.rglob("*.csv"))
        emit(bench="write_drfc_folder", rows=rows, files=ITERATIONS * args.workers, mb=round(size / 1e6, 1),
             seconds=round(dt, 3), rows_per_s=round(rows / dt))

        cold, df = timed(lambda: load(folder, cache=False), repeat=2)
        emit(bench="load_cold", rows=len(df), seconds=round(cold, 3), budget_s=1.5, threads=os.cpu_count())
        one, _ = timed(lambda: load(folder, cache=False, threads=False), repeat=2)
        emit(bench="load_cold_one_thread", rows=len(df), seconds=round(one, 3), budget_s=1.5)
        first, _ = timed(lambda: load(folder, cache_dir=cache))
        emit(bench="load_first_with_cache_write", rows=len(df), seconds=round(first, 3))
        warm, df2 = timed(lambda: load(folder, cache_dir=cache), repeat=3)
        emit(bench="load_cached", rows=len(df2), seconds=round(warm, 3), same=bool(df2.equals(df)))

        rng = np.random.default_rng(7)
        for w in range(args.workers):
            base = folder / str(w) if args.workers > 1 else folder
            eps = np.arange(ITERATIONS * per_worker, (ITERATIONS + 1) * per_worker)
            with SimtraceWriter(training_simtrace_path(base, ITERATIONS)) as writer:
                writer.write(episode_columns(eps, rng.integers(30, 210, len(eps)), rng))
        newer, df3 = timed(lambda: load(folder, cache_dir=cache))
        emit(bench="load_cached_plus_new_iteration", rows=len(df3), new_rows=len(df3) - len(df),
             seconds=round(newer, 3))
        shutil.rmtree(folder / str(0) / "training-simtrace" / f"{ITERATIONS}-iteration.csv", ignore_errors=True)
        for w in range(args.workers):
            base = folder / str(w) if args.workers > 1 else folder
            training_simtrace_path(base, ITERATIONS).unlink()

        bench_deepracer_utils(folder, cold, len(df))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def bench_deepracer_utils(folder: Path, racerlab_cold: float, rows: int) -> None:
    try:
        import logging

        from deepracer.logs import DeepRacerLog
        logging.getLogger("deepracer.logs.log").setLevel(logging.ERROR)
    except ImportError:
        emit(bench="deepracer_utils_load", skipped="deepracer-utils is not installed (pip install deepracer-utils)")
        return

    def run():
        log = DeepRacerLog(str(folder))
        log.load()
        return log.dataframe()

    dt, df = timed(run)
    emit(bench="deepracer_utils_load", rows=len(df), seconds=round(dt, 3), same_rows=len(df) == rows,
         racerlab_speedup=round(dt / racerlab_cold, 1))


if __name__ == "__main__":
    main()
