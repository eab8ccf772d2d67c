"""Disk used by a default training run: bytes per env step and the projected GB per 24 h (budget <= 1 GB).

Trains a fresh default model (`racerlab init` settings: 32 cars, lab_technical, logs defaults) for a few
minutes, then measures what its folder holds per env step:

- simtrace as plain CSV (what every iteration cost before the disk budget) and gzipped (what an iteration
  costs once it leaves the plain window), from the files the run wrote;
- metrics/TrainingMetrics.json (one AWS entry per episode; the file keeps at most 2 x 10 000 entries, older
  ones go gzipped to its archive, measured here by gzipping the run's entries the same way) and
  metrics/metrics.jsonl (one line per iteration); checkpoints (the last four and the best: a constant).

The projection multiplies by the measured collection rate (env steps per second of collection, the rate
training prints; `--rate R` adds a line at R steps/s, e.g. 18000, the fastest rate seen) over 24 h.
logs.max_mb bounds training-simtrace/ and metrics/ together (the plain window, iteration 0 and the newest
logs.plain_iterations, is inside it); `_before` is the same day with every iteration plain and no budget.
Prints one JSON line per rate.

Usage: python benchmarks/disk_usage.py [--minutes 2] [--rate STEPS_PER_S]
"""

from __future__ import annotations

import argparse
import gzip
import json
import tempfile
import time
from pathlib import Path

from racerlab import logs
from racerlab.logs.metrics import read_metrics_document
from racerlab.logs.retention import COMPRESS_LEVEL
from racerlab.model import ModelFolder, init_model
from racerlab.train import train
from racerlab.train.records import METRICS_KEEP

DAY_S = 86_400
BUDGET_GB = 1.0


def simtrace_bytes(model_dir: Path) -> dict:
    """Rows, plain bytes and gzipped bytes of every training simtrace file (plain files are gzipped here)."""
    rows = plain = packed = 0
    for path in logs.simtrace_files(logs.training_simtrace_dir(model_dir)).values():
        raw = path.read_bytes()
        text = gzip.decompress(raw) if path.suffix == ".gz" else raw
        rows += text.count(b"\n") - 1
        plain += len(text)
        packed += len(raw) if path.suffix == ".gz" else len(gzip.compress(text, COMPRESS_LEVEL, mtime=0))
    return {"rows": rows, "plain": plain, "gz": packed}


def archived_bytes(path: Path) -> int:
    """What the file's entries take once moved to TrainingMetrics.archive.jsonl.gz (as TrainingMetrics.save
    writes it)."""
    entries = read_metrics_document(path)["metrics"]
    return len(gzip.compress("".join(json.dumps(e) + "\n" for e in entries).encode("utf-8"), 6, mtime=0))


def measure(minutes: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = init_model(Path(tmp) / "m")
        t0 = time.perf_counter()
        r = train(folder.path, minutes=minutes, progress=False)
        wall = time.perf_counter() - t0
        f = ModelFolder(folder.path)
        cfg = f.config()
        return {
            "env_steps": r.env_steps, "iterations": r.iterations, "episodes": r.episodes, "wall_s": wall,
            "collect_s": sum(h["collect_seconds"] for h in r.history),
            "collected_steps": sum(h["collect_seconds"] * h["charts/env_steps_per_s"] for h in r.history),
            "simtrace": simtrace_bytes(folder.path),
            "training_metrics": logs.training_metrics_path(folder.path).stat().st_size,
            "training_metrics_archived": archived_bytes(logs.training_metrics_path(folder.path)),
            "training_metrics_entries": len(read_metrics_document(
                logs.training_metrics_path(folder.path))["metrics"]),
            "metrics_jsonl": logs.metrics_jsonl_path(folder.path).stat().st_size,
            "checkpoints": logs.disk_bytes(f.checkpoints_dir),
            "max_mb": cfg.logs.max_mb, "plain_iterations": cfg.logs.plain_iterations,
        }


def project(m: dict, rate: float | None) -> dict:
    collect_rate = m["collected_steps"] / max(m["collect_s"], 1e-9)
    rate = rate or collect_rate
    steps = rate * DAY_S
    st = m["simtrace"]
    rows = max(st["rows"], 1)
    iterations_per_day = steps / (m["env_steps"] / max(m["iterations"], 1))
    per_entry = m["training_metrics"] / max(m["training_metrics_entries"], 1)
    gb = {
        "simtrace_plain_uncapped": st["plain"] / rows * steps / 1e9,  # every iteration plain, no budget: before
        "simtrace_gz_uncapped": st["gz"] / rows * steps / 1e9,
        "training_metrics_json_unrolled": m["training_metrics"] / m["env_steps"] * steps / 1e9,  # before
        "training_metrics_json": per_entry * 2 * METRICS_KEEP / 1e9,  # at most 2 * keep entries stay in the file
        "training_metrics_archive": m["training_metrics_archived"] / m["env_steps"] * steps / 1e9,
        "metrics_jsonl": m["metrics_jsonl"] / max(m["iterations"], 1) * iterations_per_day / 1e9,
        "checkpoints": m["checkpoints"] / 1e9,
    }
    cap_gb = m["max_mb"] / 1e3 if m["max_mb"] else float("inf")
    metrics = gb["training_metrics_json"] + gb["training_metrics_archive"] + gb["metrics_jsonl"]
    # max_mb holds simtrace + metrics/; metrics are never thinned, so they can only outgrow it on their own
    gb["logs_default"] = max(min(gb["simtrace_gz_uncapped"] + metrics, cap_gb), metrics)
    total = gb["logs_default"] + gb["checkpoints"]
    before = (gb["simtrace_plain_uncapped"] + gb["training_metrics_json_unrolled"] + gb["metrics_jsonl"]
              + gb["checkpoints"])
    return {
        "bench": "disk_usage", "train_minutes": round(m["wall_s"] / 60, 2), "env_steps": m["env_steps"],
        "iterations": m["iterations"], "mean_episode_steps": round(m["env_steps"] / max(m["episodes"], 1), 1),
        "collect_env_steps_per_s": round(collect_rate), "projected_at_env_steps_per_s": round(rate),
        "bytes_per_env_step": {
            "simtrace_plain": round(st["plain"] / rows, 2), "simtrace_gz": round(st["gz"] / rows, 2),
            "training_metrics_json": round(m["training_metrics"] / m["env_steps"], 3),
            "training_metrics_archive": round(m["training_metrics_archived"] / m["env_steps"], 3),
            "metrics_jsonl": round(m["metrics_jsonl"] / m["env_steps"], 3),
        },
        "logs_max_mb": m["max_mb"], "logs_plain_iterations": m["plain_iterations"],
        "projected_gb_per_24h": {k: round(v, 3) for k, v in gb.items()},
        "projected_gb_per_24h_default": round(total, 3), "projected_gb_per_24h_before": round(before, 3),
        "budget_gb": BUDGET_GB, "within_budget": total <= BUDGET_GB,
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=2.0, help="length of the measured training run")
    ap.add_argument("--rate", type=float, action="append", default=[],
                    help="also project at this many env steps/s (repeatable), e.g. 18000")
    args = ap.parse_args()
    m = measure(args.minutes)
    for rate in (None, *args.rate):
        print(json.dumps(project(m, rate)), flush=True)


if __name__ == "__main__":
    main()
