"""Loading a 1 M-row simtrace: racerlab.analysis.load (cold, cold on one thread, cached, after a new
iteration) against deepracer-utils on the same DRfC multi-worker folder. One JSON line per measurement.

`cold_side_by_side` is the comparison to quote: a 500-file, 1 M-row single-worker DRfC folder loaded by
each tool in a fresh Python process (the tool imported first, then the load timed: lazy imports, parsing
and building the DataFrame; files in the OS cache for both), racerlab and deepracer-utils alternating
(ABBA), `--rounds` times each; the figures are the medians and the ratio of the medians, with the load
average before and after (the machine may be shared: compare ratios taken in one run).

Budget (DESIGN.md): cold load of 1 M rows <= 1.5 s; at least 4x faster than deepracer-utils side by side.

    python benchmarks/analysis_speed.py [--rows 1000000] [--workers 3] [--rounds 5] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
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
SIDE_BY_SIDE_FILES = 500

# each runs in a fresh interpreter: import the tool, then time one load of the folder in argv[1]
COLD_RACERLAB = """
import sys, time
from racerlab.analysis import load
c, t = time.process_time(), time.perf_counter(); df = load(sys.argv[1], cache=False)
print(len(df), time.perf_counter() - t, time.process_time() - c)
"""
COLD_DEEPRACER_UTILS = """
import logging, sys, time
from deepracer.logs import DeepRacerLog
logging.getLogger("deepracer.logs.log").setLevel(logging.ERROR)
c, t = time.process_time(), time.perf_counter(); log = DeepRacerLog(sys.argv[1]); log.load(); df = log.dataframe()
print(len(df), time.perf_counter() - t, time.process_time() - c)
"""


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def timed(fn, repeat: int = 1, times: list | None = None):
    """Best wall time of `repeat` runs (and the result); all times are appended to `times`."""
    runs, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        runs.append(time.perf_counter() - t)
    if times is not None:
        times.extend(runs)
    return min(runs), out


def bench_writer(tmp: Path) -> None:
    rng = np.random.default_rng(1)
    cols = episode_columns(np.arange(800), rng.integers(30, 210, 800), rng)
    n = len(cols["episode"])
    dt, _ = timed(lambda: format_rows(cols), repeat=3)
    emit(bench="simtrace_format", rows=n, seconds=round(dt, 4), rows_per_s=round(n / dt))
    for compress in (False, True):
        def write(compress=compress):
            with SimtraceWriter(tmp / "w" / "0-iteration.csv", compress=compress) as w:
                w.write(cols)
            return w.path
        dt, path = timed(write, repeat=3)
        emit(bench="simtrace_write_gz" if compress else "simtrace_write", rows=n, seconds=round(dt, 4),
             rows_per_s=round(n / dt), bytes_per_row=round(path.stat().st_size / n, 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--workers", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=5, help="fresh-process loads per tool in the side-by-side run")
    ap.add_argument("--keep", help="generate into this folder and keep it")
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="racerlab-bench-"))
    bench_writer(tmp)
    folder = Path(args.keep) if args.keep else tmp / "model"
    cache = tmp / "cache"
    per_worker = max(1, round(args.rows / (args.workers * ITERATIONS * MEAN_STEPS)))
    try:
        bench_side_by_side(tmp / "drfc-500", args.rows, args.rounds)
        dt, rows = timed(lambda: write_training_folder(folder, ITERATIONS, per_worker, args.workers, MEAN_STEPS))
        size = sum(p.stat().st_size for p in folder.rglob("*.csv"))
        emit(bench="write_drfc_folder", rows=rows, files=ITERATIONS * args.workers, mb=round(size / 1e6, 1),
             seconds=round(dt, 3), rows_per_s=round(rows / dt))

        runs: list[float] = []
        cold, df = timed(lambda: load(folder, cache=False), repeat=3, times=runs)
        emit(bench="load_cold", rows=len(df), seconds=round(cold, 3), median_s=round(float(np.median(runs)), 3),
             budget_s=1.5, threads=os.cpu_count())
        runs = []
        one, _ = timed(lambda: load(folder, cache=False, threads=False), repeat=3, times=runs)
        emit(bench="load_cold_one_thread", rows=len(df), seconds=round(one, 3),
             median_s=round(float(np.median(runs)), 3), budget_s=1.5)
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
        for w in range(args.workers):
            base = folder / str(w) if args.workers > 1 else folder
            training_simtrace_path(base, ITERATIONS).unlink()

        bench_deepracer_utils(folder, cold, len(df))

        gz = tmp / "model-gz"
        write_training_folder(gz, ITERATIONS, per_worker, args.workers, MEAN_STEPS, compress=True)
        dt, dfz = timed(lambda: load(gz, cache=False), repeat=2)
        emit(bench="load_cold_gz", rows=len(dfz), seconds=round(dt, 3), budget_s=1.5,
             mb=round(sum(p.stat().st_size for p in gz.rglob("*.gz")) / 1e6, 1))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _fresh_load(script: str, folder: Path) -> tuple[int, float, float]:
    """Rows, wall seconds and CPU seconds (all threads) of one load in a fresh interpreter."""
    out = subprocess.run([sys.executable, "-c", script, str(folder)], capture_output=True, text=True, check=True)
    rows, wall, cpu = out.stdout.split()[-3:]
    return int(rows), float(wall), float(cpu)


def bench_side_by_side(folder: Path, rows: int, rounds: int) -> None:
    """racerlab and deepracer-utils loading the same 500-file folder, alternating, each in a fresh process."""
    per_file = max(1, round(rows / (SIDE_BY_SIDE_FILES * MEAN_STEPS)))
    written = write_training_folder(folder, SIDE_BY_SIDE_FILES, per_file, 1, MEAN_STEPS, seed=3)
    os.sync()  # the folder's write-back is done before the first timed load, not during it
    try:
        import deepracer.logs  # noqa: F401
    except ImportError:
        emit(bench="cold_side_by_side", skipped="deepracer-utils is not installed (pip install deepracer-utils)")
        return
    runs: dict[str, list] = {COLD_RACERLAB: [], COLD_DEEPRACER_UTILS: []}
    rows_loaded = set()
    load_before = os.getloadavg()[0]
    for r in range(rounds):  # ABBA order: neither tool always runs first, right after the other
        for script in list(runs)[::1 if r % 2 == 0 else -1]:
            n, *t = _fresh_load(script, folder)
            rows_loaded.add(n)
            runs[script].append(t)
    ours, theirs = runs[COLD_RACERLAB], runs[COLD_DEEPRACER_UTILS]
    (a, a_cpu), (b, b_cpu) = np.median(ours, axis=0), np.median(theirs, axis=0)
    emit(bench="cold_side_by_side", files=SIDE_BY_SIDE_FILES, rows=written, same_rows=rows_loaded == {written},
         racerlab_s=round(a, 3), deepracer_utils_s=round(b, 3), ratio=round(b / a, 2), target_ratio=4.0,
         racerlab_cpu_s=round(a_cpu, 3), deepracer_utils_cpu_s=round(b_cpu, 3), cpu_ratio=round(b_cpu / a_cpu, 2),
         racerlab_runs=[round(t[0], 3) for t in ours], deepracer_utils_runs=[round(t[0], 3) for t in theirs],
         load_average=[round(load_before, 1), round(os.getloadavg()[0], 1)], cores=os.cpu_count())


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
