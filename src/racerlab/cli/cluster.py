"""`racerlab sweep`: several models trained in parallel on a Ray cluster, then raced under one set of rules."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from racerlab.errors import RacerlabError


def require_ray() -> None:
    """Ray is an optional extra: say how to get it instead of a bare ImportError."""
    if importlib.util.find_spec("ray") is None:  # not imported here: cluster.collector chooses its auth mode first
        raise RacerlabError("ray is not installed: the cluster commands need it; run "
                            "`pip install 'racerlab[cluster]'`")


def register(sub) -> None:
    p = sub.add_parser("sweep", help="train several models in parallel on Ray and rank them",
                       description="Train every model a SPEC.toml lists (hyperparameters, reward files, action "
                                   "spaces), evaluate them under the same rules and write a leaderboard.")
    p.add_argument("spec", type=Path)
    p.add_argument("--ray-address", help="an existing Ray cluster (default: a local Ray)")
    p.set_defaults(func=run_sweep)


def run_sweep(args) -> int:
    require_ray()
    from racerlab.cluster.sweep import run_sweep as sweep

    board = sweep(args.spec, address=args.ray_address)
    print(board.table())
    print(f"leaderboard: {board.json_path} and {board.png_path}")
    return 0
