"""`load(path)` and `load_metrics(path)`: the step and metrics frames analysis works on, read by `racerlab.logs`
(`racerlab.logs.frame` finds the sources, keeps the cache and builds the frame; this is its public face here)."""

from racerlab.logs.frame import FRAME_COLUMNS, derive_status, drop_absurd_rows, load, load_metrics

__all__ = ["FRAME_COLUMNS", "derive_status", "drop_absurd_rows", "load", "load_metrics"]
