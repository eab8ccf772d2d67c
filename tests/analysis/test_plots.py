"""Figures: per-cell statistics on known points (never last-write-wins), and every figure drawn from a real
training log (and from continuous-action and empty cases) without error."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from racerlab.analysis import load
from racerlab.analysis import plots as P
from racerlab.analysis.episodes import episode_summary, iteration_summary, run_metrics
from racerlab.analysis.report import fast_lap_share
from tests.analysis.test_rescore import load_track_of, train_tiny_model

# three points in cell (row 0, column 0) of a 10 cm grid, one in column 1, one outside the extent
X = [0.05, 0.07, 0.01, 0.15, 5.0]
Y = [0.05, 0.02, 0.09, 0.05, 5.0]
V = [1.0, 3.0, 8.0, 10.0, 99.0]
EXTENT = (0.0, 0.3, 0.0, 0.2)


@pytest.mark.parametrize("stat, cell00, cell01", [
    ("mean", 4.0, 10.0), ("median", 3.0, 10.0), ("min", 1.0, 10.0), ("max", 8.0, 10.0), ("sum", 12.0, 10.0),
    ("count", 3.0, 1.0), ("std", np.std([1.0, 3.0, 8.0]), 0.0), ("p50", 3.0, 10.0), ("p100", 8.0, 10.0),
])
def test_cell_statistic_on_known_points(stat, cell00, cell01):
    grid, xe, ye = P.cell_statistic(X, Y, V, stat, 0.1, EXTENT)
    assert grid.shape == (2, 3) and np.allclose(xe, [0, 0.1, 0.2, 0.3]) and np.allclose(ye, [0, 0.1, 0.2])
    assert grid[0, 0] == pytest.approx(cell00) and grid[0, 1] == pytest.approx(cell01)
    empty = grid[[0, 1, 1, 1], [2, 0, 1, 2]]
    assert (empty == 0).all() if stat == "count" else np.isnan(empty).all()


def test_cell_statistic_is_not_last_write_wins():
    # deepracer-utils' plot_track keeps the last value written into a pixel (3.0 here); a mean keeps them all
    grid, _, _ = P.cell_statistic([0.01, 0.02], [0.01, 0.02], [1.0, 3.0], "mean", 0.05, (0, 0.1, 0, 0.1))
    assert grid[0, 0] == 2.0


def test_cell_statistic_rejects_unknown_statistics():
    with pytest.raises(ValueError, match="unknown statistic"):
        P.cell_statistic(X, Y, V, "mode", 0.1, EXTENT)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    model = train_tiny_model(tmp_path_factory.mktemp("plots") / "model")
    df = load(model.path, cache=False)
    eps = episode_summary(df)
    its = iteration_summary(eps, *run_metrics(model.path))
    return df, eps, its, load_track_of(model)


def test_heatmap_cells_hold_the_statistic_of_the_steps(run):
    df, _, _, track = run
    fig = P.track_heatmap(df, track, "reward", "max", 0.2)
    mesh = next(c for c in fig.axes[0].collections if hasattr(c, "get_array") and c.get_array() is not None
                and c.get_array().ndim == 2)
    want, _, _ = P.cell_statistic(df["x"], df["y"], df["reward"], "max", 0.2, P._track_extent(track))
    got = np.ma.filled(mesh.get_array(), np.nan)
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.allclose(got[~np.isnan(got)], want[~np.isnan(want)])


def test_fast_lap_share_counts_training_laps_within_a_step_of_the_best_evaluation_lap():
    # best evaluation lap 6.0 s (iteration 2); a step is 1/15 s = 0.0667 s, so laps up to 6.1 s count (6.0 + 1.5
    # steps, a lap one step slower timed 6.0667 s). Iteration 1: 6.05 and 7.0 and an unfinished one -> 1 of 3;
    # iteration 2: 6.0 and 6.2 -> 1 of 2
    eps = pd.DataFrame({"iteration": [1, 1, 1, 2, 2], "lap_time": [6.05, 7.0, np.nan, 6.0, 6.2]})
    its = pd.DataFrame({"eval_best_lap": [6.4, 6.0]}, index=[1, 2])
    assert fast_lap_share(eps, its).tolist() == pytest.approx([1 / 3, 0.5])
    assert fast_lap_share(eps, its.assign(eval_best_lap=np.nan)) is None


def _png(fig, tmp_path, name):
    out = P.save_png(fig, tmp_path / f"{name}.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 5000
    return out


def test_every_figure_draws_from_a_training_log(run, tmp_path):
    df, eps, its, track = run
    assert "entropy" in its and "eval_completion" in its
    _png(P.training_progress(its), tmp_path, "progress")
    # the learner's figure: the run's own diagnostics (metrics.jsonl's learner/...); a discrete policy has no std,
    # its spread is the entropy
    assert its["value_rmse"].notna().all() and its["action_std_speed"].isna().all() and its["entropy"].notna().all()
    fig = P.learner_health(its, fast_lap_share(eps, its))
    assert len(fig.axes) >= 4 and fig.axes[0].lines
    _png(fig, tmp_path, "learner")
    _png(P.track_heatmap(df, track, "true_speed", "p90", 0.1, min_count=2), tmp_path, "heat")
    _png(P.track_heatmap(df, track, "reward", "count", 0.1), tmp_path, "count")
    ids = eps.nlargest(2, "progress").index.tolist()
    _png(P.episode_paths(df, track, ids, "speed"), tmp_path, "paths")
    fig = P.episode_paths(df, track, ids[:1], "action")
    assert fig.axes[0].get_legend() is not None  # one colour per discrete action, named in a legend
    _png(fig, tmp_path, "paths_action")
    _png(P.action_usage(df), tmp_path, "actions")
    _png(P.waypoint_profile(df, track), tmp_path, "waypoints")
    _png(P.lap_time_distribution(eps), tmp_path, "laps")


def test_waypoint_of_rows_is_the_previous_waypoint_by_projection(run):
    df, _, _, track = run
    wp = P.waypoint_of_rows(df, track)
    # the log's closest_waypoint is the nearer of previous and next: it is one of the two
    closest = df["closest_waypoint"].to_numpy()
    nxt = (wp + 1) % (track.num_waypoints - 1)
    assert np.mean((closest == wp) | (closest == nxt) | (closest == wp + 1)) > 0.99


def test_continuous_actions_are_binned(tmp_path):
    rng = np.random.default_rng(0)
    n = 500
    df = pd.DataFrame({"steering_angle": rng.uniform(-30, 30, n), "speed": rng.uniform(0.5, 4, n),
                       "action": -np.ones(n, int), "iteration": np.repeat([0, 1], n // 2),
                       "episode_status": ["in_progress"] * n})
    fig = P.action_usage(df, bins=(12, 8))
    assert "12 x 8 bins" in fig.axes[0].get_title()
    _png(fig, tmp_path, "continuous")


def test_no_laps_and_unknown_episodes_draw_a_note(run, tmp_path):
    df, eps, _, track = run
    fig = P.lap_time_distribution(eps.assign(complete=False, lap_time=math.nan))
    assert any("no complete lap" in t.get_text() for t in fig.axes[0].texts)
    fig = P.episode_paths(df, track, [10_000])
    assert any("no such episode" in t.get_text() for t in fig.axes[0].texts)
