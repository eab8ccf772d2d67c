"""Analysis figures. Each function returns a matplotlib `Figure` (no pyplot, no window); `save_png` writes one.

- `training_progress(iterations)`: reward, completion (training vs in-training evaluation), lap rate,
  lap times, entropy / KL, episode length per iteration.
- `learner_health(iterations, fast_laps)`: exploration (the policy's std or entropy), the value net's explained
  variance and error, the share of training laps as fast as the best evaluation lap, the evaluation's best lap
  in 1/15 s steps (why a run stops getting faster, docs/learner.md).
- `track_heatmap(df, track, column, stat, cell)`: any column aggregated per grid cell (mean, median, min,
  max, sum, std, count or a percentile like "p90"); every step counts (`cell_statistic`), never the last
  one written.
- `episode_paths(df, track, episodes, color_by)`: paths of chosen episodes coloured by speed, action or any
  column.
- `action_usage(df)`: how often each action was taken (discrete) or a steering x speed histogram
  (continuous spaces, binned).
- `waypoint_profile(df, track)`: commanded and true speed, and steering, per waypoint.
- `lap_time_distribution(episodes)`: histogram of lap times with mean and sigma markers, and lap times by
  iteration.
- `reward_vs_lap_time(comparison)`: old and new episode rewards against lap time (reward re-scoring).
- `reward_map_figure(reward_map)`: a reward over the track surface (`racerlab.analysis.reward_tools`).
- `crash_map(df, track, layout)`: where cars crashed, with the race's boxes or bot cars' starts;
  `crash_maps(df, track, layouts)` one panel per episode layout (random layouts).

One module per subject: `training` (per iteration), `track` (on the track: heatmaps, paths, reward maps, crashes),
`driving` (actions, per waypoint), `laps` (lap times, reward re-scoring), and `figure`, what they share.
"""

from __future__ import annotations

from racerlab.analysis.plots.driving import action_usage, waypoint_of_rows, waypoint_profile
from racerlab.analysis.plots.figure import _color_scale as _color_scale  # the report's tests read it
from racerlab.analysis.plots.figure import save_png
from racerlab.analysis.plots.laps import lap_time_distribution, reward_vs_lap_time
from racerlab.analysis.plots.track import (
    STATS,
    cell_statistic,
    crash_map,
    crash_maps,
    episode_paths,
    reward_map_figure,
    track_heatmap,
)
from racerlab.analysis.plots.track import (
    _track_extent as _track_extent,  # the report's pictures use it
)
from racerlab.analysis.plots.training import learner_health, training_progress

__all__ = ["STATS", "action_usage", "cell_statistic", "crash_map", "crash_maps", "episode_paths", "learner_health",
           "lap_time_distribution", "reward_map_figure", "reward_vs_lap_time", "save_png", "track_heatmap",
           "training_progress", "waypoint_of_rows", "waypoint_profile"]
