"""What the car did: `action_usage` (how often each action was taken, or a steering x speed histogram for a
continuous space) and `waypoint_profile` (commanded and true speed, and steering, per waypoint)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from racerlab.analysis.plots.figure import _action_table, _color_scale, _figure, _integer_x, _no_data
from racerlab.track import Track


def action_usage(df: pd.DataFrame, *, bins: tuple[int, int] = (13, 10), title: str | None = None):
    """Discrete spaces: steps per action (bars) and a steering x speed map with disc area ∝ use. Continuous
    spaces (action -1): a 2-D histogram of steering x speed in `bins` and both marginals."""
    run = df[df["episode_status"].astype(str) != "prepare"] if "episode_status" in df else df
    fig = _figure(13, 4.8)
    axs = fig.subplots(1, 3)
    if len(run) == 0:
        for ax in axs:
            _no_data(ax)
        return fig
    if (run["action"] >= 0).all():
        _discrete_usage(axs, run)
    else:
        _continuous_usage(axs, run, bins)
    fig.suptitle(title or f"Action space usage ({len(run):,} steps)")
    return fig


def _discrete_usage(axs, run: pd.DataFrame) -> None:
    acts = _action_table(run)
    share = run["action"].value_counts(normalize=True).reindex(acts.index, fill_value=0.0)
    labels = [f"{a}\n{r.steering_angle:+.0f}°\n{r.speed:.2f}" for a, r in acts.iterrows()]
    axs[0].bar(range(len(acts)), 100 * share.to_numpy(), color="C0")
    axs[0].set_xticks(range(len(acts)), labels, fontsize=7)
    axs[0].set_ylabel("% of steps")
    axs[0].set_title("Steps per action (index, steering, speed)", fontsize=10)
    sc = axs[1].scatter(acts["steering_angle"], acts["speed"], s=3000 * share.to_numpy() + 10,
                        c=100 * share.to_numpy(), cmap="viridis", edgecolor="black", alpha=0.8)
    for a, r in acts.iterrows():
        axs[1].annotate(str(a), (r.steering_angle, r.speed), ha="center", va="center", fontsize=7)
    axs[1].set_xlabel("steering (°, + = left)")
    axs[1].set_ylabel("speed (m/s)")
    axs[1].set_title("Action map (area and colour: % of steps)", fontsize=10)
    axs[1].invert_xaxis()  # left turns on the left
    axs[1].margins(0.15)
    axs[1].figure.colorbar(sc, ax=axs[1])  # the title says what the colour is
    _usage_by_iteration(axs[2], run, acts.index.to_numpy())


def _usage_by_iteration(ax, run: pd.DataFrame, actions: np.ndarray) -> None:
    tab = pd.crosstab(run["iteration"], run["action"], normalize="index").reindex(columns=actions, fill_value=0)
    bottom = np.zeros(len(tab))
    norm, cmap = _color_scale(actions.astype(float), True)
    for a in actions:
        ax.bar(tab.index, 100 * tab[a].to_numpy(), bottom=bottom, color=cmap(norm(a)), width=1.0, label=str(a))
        bottom += 100 * tab[a].to_numpy()
    ax.set_xlabel("iteration")
    ax.set_ylabel("% of steps")
    ax.set_title("Action share per iteration", fontsize=10)
    _integer_x(ax)
    ax.legend(fontsize=6, ncol=2, title="action", title_fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))


def _continuous_usage(axs, run: pd.DataFrame, bins: tuple[int, int]) -> None:
    steer = run["steering_angle"].to_numpy()
    speed = run["speed"].to_numpy()
    h = axs[0].hist2d(steer, speed, bins=bins, cmap="viridis", cmin=1)
    axs[0].set_xlabel("steering (°, + = left)")
    axs[0].set_ylabel("speed (m/s)")
    axs[0].invert_xaxis()
    axs[0].set_title(f"Steering x speed ({bins[0]} x {bins[1]} bins)", fontsize=10)
    axs[0].figure.colorbar(h[3], ax=axs[0], label="steps")
    axs[1].hist(steer, bins=2 * bins[0], color="C0")
    axs[1].set_xlabel("steering (°)")
    axs[1].set_title("Steering", fontsize=10)
    axs[2].hist(speed, bins=2 * bins[1], color="C1")
    axs[2].set_xlabel("speed (m/s)")
    axs[2].set_title("Speed", fontsize=10)


# ---------------------------------------------------------------------------------------------------------
# per waypoint


def waypoint_of_rows(df: pd.DataFrame, track: Track | None) -> np.ndarray:
    """The waypoint each row is at: the previous waypoint along the track (by projection; the log's
    closest_waypoint when there is no track). The closing duplicate of a loop counts as waypoint 0."""
    if track is None:
        return df["closest_waypoint"].to_numpy()
    from racerlab.analysis.rescore import track_columns

    wp = track_columns(track, df["x"].to_numpy(), df["y"].to_numpy())["prev_waypoint"]
    return np.where(wp >= track.num_waypoints - 1, 0, wp) if track.closed else wp


def waypoint_profile(df: pd.DataFrame, track: Track | None = None, *, title: str | None = None):
    """Mean commanded speed, mean true speed (with its 10-90 % band) and mean steering (with its 25-75 % band)
    per waypoint, over all steps of `df` (prepare steps left out)."""
    from racerlab.analysis.episodes import step_kinematics

    run_mask = (df["episode_status"].astype(str) != "prepare").to_numpy() if "episode_status" in df else \
        np.ones(len(df), bool)
    kin = step_kinematics(df)
    wp = waypoint_of_rows(df, track)[run_mask]
    frame = pd.DataFrame({"wp": wp, "speed": df["speed"].to_numpy()[run_mask],
                          "true": kin["true_speed"].to_numpy()[run_mask],
                          "steer": df["steering_angle"].to_numpy()[run_mask]})
    g = frame.groupby("wp")
    fig = _figure(13, 6)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    if len(frame) == 0:
        _no_data(ax1)
        return fig
    idx = g.size().index.to_numpy()
    ax1.plot(idx, g["speed"].mean(), label="commanded (mean)", color="C0")
    ax1.plot(idx, g["true"].mean(), label="true, from positions (mean)", color="C1")
    ax1.fill_between(idx, g["true"].quantile(0.1), g["true"].quantile(0.9), color="C1", alpha=0.2,
                     label="true, 10-90 %")
    ax1.set_ylabel("speed (m/s)")
    ax1.legend(fontsize=8)
    ax2.plot(idx, g["steer"].mean(), color="C2", label="mean")
    ax2.fill_between(idx, g["steer"].quantile(0.25), g["steer"].quantile(0.75), color="C2", alpha=0.2,
                     label="25-75 %")
    ax2.axhline(0, color="black", lw=0.6)
    ax2.set_ylabel("steering (°, + = left)")
    ax2.set_xlabel("waypoint")
    ax2.legend(fontsize=8)
    if track is not None:
        _shade_turns(ax1, ax2, track)
    for a in (ax1, ax2):
        a.grid(alpha=0.3)
    fig.suptitle(title or f"Speed and steering per waypoint ({len(frame):,} steps)")
    return fig


def _shade_turns(ax1, ax2, track: Track) -> None:
    """Grey bands where the centre line turns tighter than 2 m radius, to read the profile against the track."""
    k = np.abs(track.curvature)
    tight = k > 0.5
    edges = np.flatnonzero(np.diff(np.concatenate([[0], tight.astype(int), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        for ax in (ax1, ax2):
            ax.axvspan(a - 0.5, b - 0.5, color="#999999", alpha=0.12, lw=0)
