"""Writing and reading the DeepRacer log formats, in a model folder that deepracer-utils reads as is.

Model-folder layout (the DRfC single-worker layout; `deepracer.logs.DeepRacerLog(model_dir).load()`
detects it as `DRFC_MODEL_SINGLE_WORKERS` because `training-simtrace/` sits at the top)::

    <model>/
      training-simtrace/<n>-iteration.csv     one per training iteration (19 AWS columns, header row)
      metrics/TrainingMetrics.json            AWS schema, one entry per episode (deepracer-utils TrainingMetrics)
      metrics/metrics.jsonl                   racerlab's own metrics, one JSON object per iteration
      evaluation-<YYYYmmddHHMMSS>/            one per evaluation run (deepracer-utils: stream = the 14 digits)
        evaluation-simtrace/0-iteration.csv
        EvalMetrics.json                      AWS evaluation schema
      model/model_metadata.json               copies made by `export_drfc_metadata`, so that deepracer-utils'
      ip/hyperparameters.json                 action_space() and hyperparameters() work (optional for load())

deepracer-utils 1.5.6 reads plain `.csv` only (its glob ends in `.csv`; the bytes go to `pandas.read_csv`
undecompressed) and counts episodes per iteration from iteration 0. A training therefore keeps iteration 0
and the newest `logs.plain_iterations` plain, gzips older ones to `.csv.gz` and, past `logs.max_mb`, thins
the oldest gzipped ones (`SimtraceRetention`); `racerlab.analysis.load` reads all of them. Other bounded
modes: `SimtraceWriter(..., sample_episodes=k)` (every k-th episode, still plain CSV; deepracer-utils'
`unique_episode` numbering assumes no gaps) and `compress=True` (every file gzipped).

Writers:
- `SimtraceRetention(folder, plain, max_bytes)`: `.enforce()` gzips and thins a training-simtrace folder.
- `SimtraceWriter(path, compress=False, *, sample_episodes=1)`: `.write(columns)` appends a batch (the 19
  `SIMTRACE_COLUMNS` as equal-length arrays, vectorised formatting), `.close()` publishes atomically.
- `TrainingMetrics(path, best_model_metric="progress")`, `EvalMetrics(path)`: `.add(entries)`, `.save()`.
- `MetricsLog(path, fsync=False)`: `.append(entry)` one JSON line, flushed.
- `atomic_write_text`, `atomic_write_bytes`, `atomic_write_json`: temp name + rename.
- `scratch_dir(kind)`: a private temporary folder for a `with` block, in racerlab's one place (`logs.scratch`).

Readers: `load(path)` (any log source to one step DataFrame, cached; `logs.frame`, re-exported as
`racerlab.analysis.load`), `load_metrics(path)` (TrainingMetrics/EvalMetrics JSON to a DataFrame),
`read_metrics_jsonl`, `follow_metrics_jsonl`.
"""

from racerlab.logs.atomic import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    remove_stale_temps,
)
from racerlab.logs.layout import (
    disk_bytes,
    eval_layouts_path,
    eval_metrics_path,
    eval_simtrace_path,
    evaluation_dir,
    evaluation_dirs,
    export_drfc_metadata,
    metrics_jsonl_path,
    new_evaluation_dir,
    remove_training_simtrace_after,
    simtrace_files,
    training_metrics_path,
    training_simtrace_dir,
    training_simtrace_path,
)
from racerlab.logs.metrics import (
    BEST_CHECKPOINT_RULES,
    BEST_LAP_MEANING,
    BEST_LAP_NAME,
    EVAL_METRICS_KEYS,
    TRAINING_METRICS_KEYS,
    EvalMetrics,
    LogFileError,
    MetricsLog,
    TrainingMetrics,
    best_eval_lap,
    finite_json,
    follow_metrics_jsonl,
    last_metrics_entry,
    read_metrics_jsonl,
)
from racerlab.logs.retention import SimtraceRetention, thin_simtrace
from racerlab.logs.scratch import pid_alive, scratch_dir
from racerlab.logs.simtrace import SIMTRACE_COLUMNS, SimtraceWriter, format_row, format_rows, write_simtrace

_READERS = ("FRAME_COLUMNS", "load", "load_metrics")  # pandas loads with the first read, not with `import racerlab`


def __getattr__(name: str):
    if name in _READERS:
        from racerlab.logs import frame

        return getattr(frame, name)
    raise AttributeError(f"module 'racerlab.logs' has no attribute {name!r}")

__all__ = [
    "BEST_CHECKPOINT_RULES", "BEST_LAP_MEANING", "BEST_LAP_NAME", "best_eval_lap",
    "EVAL_METRICS_KEYS", "FRAME_COLUMNS", "SIMTRACE_COLUMNS", "TRAINING_METRICS_KEYS",
    "EvalMetrics", "LogFileError", "MetricsLog", "SimtraceRetention", "SimtraceWriter", "TrainingMetrics",
    "atomic_write_bytes", "atomic_write_json", "atomic_write_text", "disk_bytes", "eval_layouts_path",
    "eval_metrics_path",
    "eval_simtrace_path", "evaluation_dir", "evaluation_dirs", "export_drfc_metadata", "format_row",
    "finite_json", "follow_metrics_jsonl", "format_rows", "last_metrics_entry", "load", "load_metrics",
    "metrics_jsonl_path",
    "new_evaluation_dir", "pid_alive", "read_metrics_jsonl", "remove_stale_temps",
    "remove_training_simtrace_after", "scratch_dir", "simtrace_files", "training_metrics_path", "training_simtrace_dir",
    "training_simtrace_path", "thin_simtrace", "write_simtrace",
]
