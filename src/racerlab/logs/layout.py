"""Where the logs live in a model folder: the DRfC single-worker layout, which deepracer-utils reads as is.

deepracer-utils 1.5.6 (`deepracer.logs.handler.FSFileHandler.determine_root_folder_type`) recognises a
local folder as `DRFC_MODEL_SINGLE_WORKERS` when `<model>/training-simtrace/` exists (and there is no
`<model>/sim-trace/`), and then globs:

- training:   `<model>/training-simtrace/*-iteration.csv` (iteration = the number before `-iteration`)
- evaluation: `<model>/evaluation-<14 digits>/evaluation-simtrace/0-iteration.csv` (stream = the digits)
- metadata:   `<model>/model/model_metadata.json` and `<model>/ip/hyperparameters.json` (optional: a
  missing file is only a warning, but `action_space()` and `hyperparameters()` then fail)
- its `TrainingMetrics` class reads `<model>/metrics/TrainingMetrics.json` (`_<k>` suffix for worker k > 0).

It reads only plain `.csv` (the glob ends in `.csv` and the bytes go to `pandas.read_csv` without
decompression), so a gzipped simtrace is for racerlab's own reader only; see `SimtraceWriter`.
"""

from __future__ import annotations

import os
import re
from datetime import datetime
from pathlib import Path

from racerlab.logs.atomic import atomic_write_bytes

TRAINING_SIMTRACE_DIR = "training-simtrace"
EVALUATION_SIMTRACE_DIR = "evaluation-simtrace"
METRICS_DIR = "metrics"
EVALUATION_PREFIX = "evaluation-"
STAMP_FORMAT = "%Y%m%d%H%M%S"

_ITERATION_FILE = re.compile(r"^(\d+)-iteration\.csv(\.gz)?$")


def training_simtrace_dir(model_dir: str | os.PathLike) -> Path:
    """`<model>/training-simtrace`."""
    return Path(model_dir) / TRAINING_SIMTRACE_DIR


def training_simtrace_path(model_dir: str | os.PathLike, iteration: int, compress: bool = False) -> Path:
    """`<model>/training-simtrace/<iteration>-iteration.csv` (`.csv.gz` when `compress`)."""
    return training_simtrace_dir(model_dir) / _iteration_name(iteration, compress)


def training_metrics_path(model_dir: str | os.PathLike, worker: int = 0) -> Path:
    """`<model>/metrics/TrainingMetrics.json` (`TrainingMetrics_<k>.json` for worker k > 0, as DRfC)."""
    suffix = f"_{worker}" if worker else ""
    return Path(model_dir) / METRICS_DIR / f"TrainingMetrics{suffix}.json"


def metrics_jsonl_path(model_dir: str | os.PathLike) -> Path:
    """`<model>/metrics/metrics.jsonl`: racerlab's own per-iteration metrics (no DeepRacer tool reads it)."""
    return Path(model_dir) / METRICS_DIR / "metrics.jsonl"


def evaluation_dir(model_dir: str | os.PathLike, stamp: datetime | str) -> Path:
    """`<model>/evaluation-<YYYYmmddHHMMSS>`: one evaluation run (the 14 digits are what deepracer-utils needs)."""
    if isinstance(stamp, datetime):
        stamp = stamp.strftime(STAMP_FORMAT)
    if not re.fullmatch(r"\d{14}", stamp):
        raise ValueError(f"evaluation stamp must be 14 digits YYYYmmddHHMMSS, got {stamp!r}")
    return Path(model_dir) / f"{EVALUATION_PREFIX}{stamp}"


def new_evaluation_dir(model_dir: str | os.PathLike, when: datetime | None = None) -> Path:
    """Create and return a fresh evaluation folder stamped `when` (now), moving a second on when taken."""
    when = when or datetime.now()
    for _ in range(3600):
        folder = evaluation_dir(model_dir, when)
        try:
            folder.mkdir(parents=True)
            return folder
        except FileExistsError:
            when = datetime.fromtimestamp(when.timestamp() + 1)
    raise RuntimeError(f"no free evaluation folder name in {model_dir}")


def eval_simtrace_path(eval_dir: str | os.PathLike, iteration: int = 0, compress: bool = False) -> Path:
    """`<eval_dir>/evaluation-simtrace/<iteration>-iteration.csv`; deepracer-utils reads iteration 0 only."""
    return Path(eval_dir) / EVALUATION_SIMTRACE_DIR / _iteration_name(iteration, compress)


def eval_metrics_path(eval_dir: str | os.PathLike) -> Path:
    """`<eval_dir>/EvalMetrics.json` (the AWS evaluation schema)."""
    return Path(eval_dir) / "EvalMetrics.json"


def eval_layouts_path(eval_dir: str | os.PathLike) -> Path:
    """`<eval_dir>/layouts.json`: where each episode's boxes or bot cars stood (racerlab's, races with objects)."""
    return Path(eval_dir) / "layouts.json"


def evaluation_dirs(model_dir: str | os.PathLike) -> list[Path]:
    """The model's evaluation folders, oldest first."""
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        return []
    found = [p for p in model_dir.iterdir() if p.is_dir() and re.fullmatch(r"evaluation-\d{14}", p.name)]
    return sorted(found)


def simtrace_files(folder: str | os.PathLike) -> dict[int, Path]:
    """`{iteration: path}` of the `<n>-iteration.csv(.gz)` files directly in `folder`."""
    folder = Path(folder)
    found: dict[int, Path] = {}
    if folder.is_dir():
        for p in folder.iterdir():
            m = _ITERATION_FILE.match(p.name)
            if m:
                found[int(m.group(1))] = p
    return dict(sorted(found.items()))


def remove_training_simtrace_after(model_dir: str | os.PathLike, iteration: int) -> list[Path]:
    """Delete training simtraces of iterations > `iteration` (used when resuming from an older checkpoint)."""
    removed = []
    for n, p in simtrace_files(training_simtrace_dir(model_dir)).items():
        if n > iteration:
            p.unlink(missing_ok=True)
            removed.append(p)
    return removed


def export_drfc_metadata(model_dir: str | os.PathLike) -> list[Path]:
    """Copy `<model>/model_metadata.json` and `hyperparameters.json` to `model/` and `ip/`, where
    deepracer-utils looks for them (so `DeepRacerLog.action_space()` and `.hyperparameters()` work).

    Returns the copies written; a missing source is skipped.
    """
    model_dir = Path(model_dir)
    written = []
    for src, dst in (("model_metadata.json", "model/model_metadata.json"),
                     ("hyperparameters.json", "ip/hyperparameters.json")):
        if (model_dir / src).is_file():
            written.append(atomic_write_bytes(model_dir / dst, (model_dir / src).read_bytes()))
    return written


def _iteration_name(iteration: int, compress: bool) -> str:
    if int(iteration) != iteration or iteration < 0:
        raise ValueError(f"iteration must be a non-negative integer, got {iteration!r}")
    return f"{int(iteration)}-iteration.csv" + (".gz" if compress else "")


def disk_bytes(folder: str | os.PathLike) -> int:
    """Total size of the files under `folder` (0 when it does not exist)."""
    folder = Path(folder)
    if not folder.exists():
        return 0
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


__all__ = [
    "disk_bytes", "eval_metrics_path", "eval_simtrace_path", "evaluation_dir", "evaluation_dirs",
    "export_drfc_metadata", "metrics_jsonl_path", "new_evaluation_dir", "remove_training_simtrace_after",
    "simtrace_files", "training_metrics_path", "training_simtrace_dir", "training_simtrace_path",
]
