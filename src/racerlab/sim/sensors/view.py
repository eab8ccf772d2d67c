"""A picture of what the sensors see: the track from above with cars at several points of a lap, and
beside each car its camera frame and its lidar scan (`racerlab sim view`). In a race with objects the boxes
or bot cars are drawn from above, in the camera frames (as the camera renders them) and in the lidar panels."""

from __future__ import annotations

import math

import numpy as np

from racerlab.sim import _kernels as K
from racerlab.sim.core import Simulator
from racerlab.sim.sensors.camera import Camera
from racerlab.sim.sensors.geometry import CAMERA_HFOV_RAD, lidar_position
from racerlab.sim.sensors.lidar import MAX_RANGE_M, Lidar
from racerlab.sim.sensors.look import DomainRandomization
from racerlab.track import Track

CAR_COLORS = ("#e4572e", "#4c9be8", "#f3a712", "#7bc950", "#b07bd6", "#2ec4b6", "#ff6f91", "#c0c0c0")
LIDAR_HIT = "#e4572e"
BOX_COLOR, BOT_COLOR = "#c8a06e", "#5a64be"  # TrackLook.box, TrackLook.bot_car


def place_cars(track: Track, cars: int, seed: int = 0, race=None) -> Simulator:
    """A simulator with `cars` cars on the centre line, evenly spread over the lap from its start (a start near a
    box moves to the other lane, as in training)."""
    sim = Simulator(track, cars, seed=seed, race=race)
    sim.reset(start_ndist=np.arange(cars) / cars)
    return sim


def sensor_view(track: Track, cars: int = 4, *, randomize: bool = False, walls: bool = False, seed: int = 0,
                race=None):
    """A matplotlib Figure: the track with `cars` numbered cars (and the race's objects: `race` as `Simulator`
    takes it), and per car its camera frame and lidar scan."""
    from matplotlib.figure import Figure

    from racerlab.track.plot import draw_track

    sim = place_cars(track, cars, seed, race)
    frames = Camera(sim, randomization=DomainRandomization() if randomize else None).render()
    ranges = Lidar(sim, walls=walls).scan()
    fig = Figure(figsize=(13.5, max(2.3 * cars, 6.0)))
    grid = fig.add_gridspec(cars, 3, width_ratios=[2.4, 1.6, 1.0], wspace=0.08, hspace=0.25)
    ax = fig.add_subplot(grid[:, 0])
    draw_track(track, ax, waypoint_numbers=False, legend=False)
    if sim.objects is not None:
        for i in range(cars):  # each car's own objects (the same for fixed layouts)
            _draw_objects(ax, sim, i, np.eye(3))
    for i in range(cars):
        _draw_car(ax, sim.car[i], i)
        _draw_frame(fig.add_subplot(grid[i, 1]), frames[i, :, :, 0], i, randomize)
        _draw_scan(fig.add_subplot(grid[i, 2]), sim, i, ranges[i], walls)
    look = "domain-randomized looks" if randomize else "default look"
    seen = "track borders as walls" if walls else "as AWS: no walls"
    if sim.objects is not None:
        seen += f", {'bot cars' if _cars(sim) else 'boxes'} per car: {sim.objects.num_objects}"
    fig.suptitle(f"{track.name}: camera 160×120 greyscale ({look}) and lidar 64 rays ({seen})", fontsize=11)
    return fig


def _cars(sim) -> bool:
    return bool(getattr(sim.objects, "bots", False) or getattr(sim.objects, "racers", False))


def _draw_objects(ax, sim: Simulator, i: int, frame: np.ndarray) -> None:
    """Car i's objects to scale; `frame` (3, 3) maps world (x, y, 1) to the drawing's (x, y) (rows 0 and 1)."""
    from matplotlib.patches import Polygon

    o = sim.objects
    hl, hw = 0.5 * o.box_size_m
    color = BOT_COLOR if _cars(sim) else BOX_COLOR
    corners = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    for (x, y), yaw in zip(o.xy[i], o.yaw[i], strict=True):
        c, s = math.cos(yaw), math.sin(yaw)
        world = np.column_stack([x + corners[:, 0] * c - corners[:, 1] * s, y + corners[:, 0] * s + corners[:, 1] * c,
                                 np.ones(4)])
        xy = world @ frame[:2].T
        patch = ax.add_patch(Polygon(xy, closed=True, facecolor=color, edgecolor="black", lw=0.6, zorder=4.5))
        patch.set_clip_path(ax.patch)  # objects beyond the lidar panel's limits stay inside its frame


def _draw_car(ax, car, i: int) -> None:
    x, y, yaw = car[K.CX], car[K.CY], car[K.CYAW]
    color = CAR_COLORS[i % len(CAR_COLORS)]
    half = 0.5 * CAMERA_HFOV_RAD
    reach = 1.2
    wedge = [(x, y)] + [(x + reach * math.cos(yaw + a), y + reach * math.sin(yaw + a)) for a in (half, -half)]
    ax.fill(*zip(*wedge, strict=True), color=color, alpha=0.35, lw=0, zorder=4)
    ax.plot(x, y, marker=(3, 0, math.degrees(yaw) - 90), ms=11, color=color, mec="black", mew=0.6, zorder=5)
    ax.annotate(str(i + 1), (x, y), xytext=(7, 7), textcoords="offset points", fontsize=11, weight="bold",
                color=color, zorder=6)


def _draw_frame(ax, img: np.ndarray, i: int, randomize: bool) -> None:
    ax.imshow(img, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    for side in ax.spines.values():
        side.set_color(CAR_COLORS[i % len(CAR_COLORS)])
        side.set_linewidth(2.5)
    ax.set_title(f"car {i + 1}: camera", fontsize=9)


def _draw_scan(ax, sim: Simulator, i: int, ranges: np.ndarray, walls: bool) -> None:
    """The scan in the car's frame, x ahead pointing up: rays, hits, the 1 m limit, the car and nearby borders."""
    from racerlab.sim.sensors.geometry import lidar_ray_angles

    angles = lidar_ray_angles()
    mx = lidar_position()
    # car frame (x ahead, y left) drawn with ahead up and left to the left: screen = (-y, x)
    for a, r in zip(angles, ranges, strict=True):
        hit = r < MAX_RANGE_M
        ex, ey = mx + r * math.cos(a), r * math.sin(a)
        ax.plot([0.0, -ey], [mx, ex], color=LIDAR_HIT if hit else "#9aa5b1", lw=0.8 if hit else 0.5)
        if hit:
            ax.plot(-ey, ex, "o", ms=2.5, color=LIDAR_HIT)
    t = np.linspace(0, 2 * math.pi, 200)
    ax.plot(-MAX_RANGE_M * np.sin(t), mx + MAX_RANGE_M * np.cos(t), color="#9aa5b1", lw=0.6, ls=":")
    ax.add_patch(_car_patch())
    _draw_borders(ax, sim, i)
    if sim.objects is not None:
        x, y, yaw = sim.car[i, K.CX], sim.car[i, K.CY], sim.car[i, K.CYAW]
        c, s = math.cos(yaw), math.sin(yaw)
        # world -> car frame (fx ahead, fy left) -> screen (-fy, fx)
        to_screen = np.array([[s, -c, -s * x + c * y], [c, s, -c * x - s * y], [0.0, 0.0, 1.0]])
        _draw_objects(ax, sim, i, to_screen)
    ax.set_xlim(-1.25, 1.25)
    ax.set_ylim(-1.2, 1.3)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(f"car {i + 1}: lidar" + ("" if walls or sim.objects is not None else " (nothing to hit)"),
                 fontsize=9)


def _car_patch():
    from matplotlib.patches import Rectangle

    return Rectangle((-0.1, -0.08), 0.2, 0.3, facecolor="#333333", edgecolor="black", lw=0.6, zorder=3)


def _draw_borders(ax, sim: Simulator, i: int) -> None:
    """The track borders within reach, in the car's frame, for orientation."""
    x, y, yaw = sim.car[i, K.CX], sim.car[i, K.CY], sim.car[i, K.CYAW]
    c, s = math.cos(yaw), math.sin(yaw)
    for border in (sim.track.inner, sim.track.outer):
        dx, dy = border[:, 0] - x, border[:, 1] - y
        fx, fy = c * dx + s * dy, -s * dx + c * dy
        near = np.hypot(fx, fy) < 2.0
        if near.any():
            ax.plot(np.where(near, -fy, np.nan), np.where(near, fx, np.nan), color="#5c6670", lw=1.0, zorder=4)
