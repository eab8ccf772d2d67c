"""`racerlab report MODEL_OR_LOGDIR`: one self-contained HTML analysis of a training or evaluation log."""

from __future__ import annotations

import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("report", help="write one self-contained HTML analysis of a model folder or logs",
                       description="Analyse the step logs found at PATH (a racerlab model folder, a DRfC or "
                                   "console folder, SIM_TRACE_LOG logs, a simtrace CSV or a console .tar.gz) into "
                                   "ONE HTML file with every figure embedded: training progress, lap times, "
                                   "best episodes, track heatmaps, paths, action usage, speed and steering per "
                                   "waypoint. Prints the file's path.")
    p.add_argument("path", type=Path, metavar="MODEL_OR_LOGDIR", help="model folder, log folder or log file")
    p.add_argument("--out", type=Path, metavar="FILE.html",
                   help="where to write it (default: report.html in the folder, or <file>-report.html)")
    p.add_argument("--track", help="track name or file (default: the model folder's training track, or the "
                                   "known track as long as the log's track_len)")
    p.add_argument("--kind", choices=["auto", "training", "evaluation", "leaderboard"], default="auto",
                   help="which logs to analyse when there are several kinds (default: training if any)")
    p.set_defaults(func=run_report)


def run_report(args) -> int:
    from racerlab.cli import require_path

    require_path(args.path)
    from racerlab.analysis.report import write_report

    def say(text):  # a 1 M-step log takes a while: say what is being done (stderr; stdout is the file's path)
        print(f"report: {text}", file=sys.stderr, flush=True)

    out = write_report(args.path, args.out, args.track, kind=args.kind, progress=say)
    print(out)
    return 0
