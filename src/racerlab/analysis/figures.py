"""The quickstart's two pictures, for anyone who has an evaluation and a model folder: the evaluation's path on
the track coloured by speed (`draw_lap`) and the report's training-progress figure (`draw_curve`)."""

from __future__ import annotations

from pathlib import Path


def draw_lap(res, track, path: Path) -> None:
    """The evaluation's path on the track, coloured by the speed derived from positions."""
    import numpy as np
    import pandas as pd
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    from racerlab.spec import STEP_S
    from racerlab.track import load as load_track
    from racerlab.track.plot import draw_track

    df = pd.read_csv(res.files["simtrace"])
    xy = df[["X", "Y"]].to_numpy()
    fig = Figure(figsize=(9, 7))
    ax = fig.add_subplot()
    draw_track(load_track(track), ax=ax, waypoint_numbers=False)
    step = np.hypot(*np.diff(xy, axis=0).T)
    keep = step < 0.5  # no line across a reset after an off-track
    segs = np.stack([xy[:-1], xy[1:]], axis=1)[keep]
    lc = LineCollection(segs, array=(step / STEP_S)[keep], cmap="plasma", linewidths=2.0, zorder=5)
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed (m/s)", shrink=0.7)
    ax.set_title(f"{res.model} ({res.checkpoint}) on {res.track}: {res.text}")
    fig.savefig(path, dpi=120, bbox_inches="tight")


def draw_curve(model: Path, path: Path) -> None:
    """The report's training-progress figure (reward, completion, lap times, entropy per iteration)."""
    from racerlab.analysis import load
    from racerlab.analysis.episodes import episode_summary, iteration_summary, run_metrics, step_kinematics
    from racerlab.analysis.plots import save_png, training_progress
    from racerlab.analysis.report import count_iterations_from_one

    df = load(model)
    its = iteration_summary(episode_summary(df, step_kinematics(df)), *run_metrics(model))
    count_iterations_from_one(its=its)  # as the console printed them
    save_png(training_progress(its, title=f"{model.name}: training progress"), path)
