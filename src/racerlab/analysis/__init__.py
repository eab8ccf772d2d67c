"""Log analysis: DataFrames from any DeepRacer log source (`load`), and later aggregations, plots and
reward re-scoring."""

from racerlab.analysis.load import FRAME_COLUMNS, load, load_metrics

__all__ = ["FRAME_COLUMNS", "load", "load_metrics"]
