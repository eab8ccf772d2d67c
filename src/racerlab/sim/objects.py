"""Objects on the track (object avoidance): the race settings, AWS obstacle placement, the crash rule, and the
`objects_*` reward params.

Every car of a batch has its own objects (`ObjectSet`, arrays with the car axis first), placed again at each
of its resets as the AWS simulator does (`ObstaclesCtrl.reset_agent`, reference next_capabilities §A.1):

- `object_positions` ((fraction of the lap, lane) pairs) put the boxes where they say: lane 1 is the inner
  lane, -1 the outer one;
- otherwise `number_of_obstacles` start evenly spaced at `linspace(min_d, L - 1, N)` metres of arc length,
  lanes alternating from the inner one; with `randomize_obstacle_locations` each box in a shuffled order is
  re-drawn uniformly between its neighbours (keeping `min_d` to each, the first at least `min_d` from the
  start line, the last at most `L - 1`), then every box gets a random lane;
- a box stands on its lane line (the midline between centre line and border) at the point nearest the centre
  line's point at that arc length, turned along the lane.

`min_distance_between_obstacles` is a percentage of the lap, `min_d = value / 100 * L`, every episode. AWS
converts the stored value again at every reset (the value shrinks by L/100 each episode: 0.46 m, 0.107 m,
0.025 m ... on reInvent2019), so from the third episode on its random layouts have no minimum gap; racerlab
keeps the intended minimum (the difference is written down in docs/objects.md).

Crash rule (facts §2, next_capabilities §A.4): a car has crashed when one of the four corners of its footprint
(0.32352 m long x 0.1961 m wide, centred on the base pose) lies strictly inside an object's footprint (a box's
is 0.5 m along its lane x 0.4 m across, the box plus 0.1 m). Only the car's corners are tested.
"""

from __future__ import annotations

import math

import numpy as np

from racerlab.errors import ConfigError
from racerlab.sim.sensors.geometry import CAMERA_PITCH_RAD, camera_position
from racerlab.spec import MODEL_POINT_AHEAD_M, RaceConfig
from racerlab.track import Track

BOX_SIZE_M = (0.40, 0.30)  # the box model (along the lane, across): what the lidar and camera see
BOX_FOOTPRINT_M = (0.5, 0.4)  # (along the lane, across): ObstacleDimensions.BOX_OBSTACLE_DIMENSION (0.4, 0.5)
CAR_FOOTPRINT_M = (0.32352, 0.1961)  # (length, width): BOT_CAR_DIMENSION, the agent's crash footprint
OBSTACLE_Z_M = 0.1
END_MARGIN_M = 1.0  # the last obstacle stays this far before the end of the lap
FEATURE_OBJECTS = 2  # the `features` observation gains the nearest objects ahead, (x ahead, y left) / 2 m each
RESET_BEHIND_DIST_M = 1.0  # evaluation: after a crash the car restarts this far behind the box, other lane
CLOSEST_OBJ_GAP_M = 1.0  # a start this near an object moves to the other lane (rollout_agent_ctrl)
CAMERA_HFOV_RAD = 1.13
CAMERA_ASPECT = 4 / 3  # 640 x 480
CAMERA_FAR_M = 300.0
CAMERA_NEAR_M = 0.02


def as_race(value) -> RaceConfig | None:
    """A `RaceConfig`, its keyword dict, a race type name, or None (a time trial)."""
    if value is None or isinstance(value, RaceConfig):
        return value
    if isinstance(value, str):
        return RaceConfig(type=value, number_of_obstacles=6 if value == "object_avoidance" else 0)
    return RaceConfig.from_mapping(value)


# ---- placement -----------------------------------------------------------------------------------------
def obstacle_arcs(race: RaceConfig, length: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(arc lengths along the centre line in m, lanes +1 inner / -1 outer) of one episode's boxes."""
    if race.num_bot_cars:  # bot cars: evenly spaced, min distance in metres, lanes alternating (BotCarsCtrl)
        n = race.num_bot_cars
        d = np.linspace(race.min_distance_between_bot_cars, length - END_MARGIN_M, n)
        return d, np.where(np.arange(n) % 2 == 0, 1, -1)
    if race.object_positions:
        pos = np.array(race.object_positions, dtype=np.float64)
        return pos[:, 0] * length, pos[:, 1].astype(np.int64)
    n = race.num_obstacles
    min_d = race.min_distance_between_obstacles / 100.0 * length
    last = length - END_MARGIN_M
    if n and min_d > last:
        raise ConfigError(f"{race.where}: min_distance_between_obstacles {race.min_distance_between_obstacles} % "
                          f"of this {length:.2f} m lap leaves no room for obstacles; use a smaller value")
    d = np.linspace(min_d, last, n)
    if race.randomize_obstacle_locations:
        for i in rng.permutation(n):
            lo = d[i - 1] + min_d if i > 0 else min_d
            hi = d[i + 1] - min_d if i < n - 1 else last
            if lo <= hi:
                d[i] = rng.uniform(lo, hi)
        lanes = rng.choice(np.array([1, -1]), size=n)
    else:
        lanes = np.where(np.arange(n) % 2 == 0, 1, -1)
    return d, lanes


def _lane(track: Track, border: np.ndarray) -> Track:
    """The lane line between the centre line and `border`, as a polyline with arc length and projection."""
    mid = 0.5 * (track.center + border)
    return Track("lane", mid, mid, mid, track.closed)


class Lanes:
    """The inner and outer lane lines of a track in one driving direction."""

    def __init__(self, track: Track):
        self.track = track
        self.inner = _lane(track, track.inner)
        self.outer = _lane(track, track.outer)

    def poses(self, arcs: np.ndarray, lanes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(xy (m, 2), yaw (m,)) of boxes at centre-line arc lengths `arcs` on `lanes` (+1 inner, -1 outer)."""
        xy = np.empty((arcs.size, 2))
        yaw = np.empty(arcs.size)
        centre = self.track.point_at(arcs).reshape(-1, 2)
        for flag, lane in ((1, self.inner), (-1, self.outer)):
            sel = lanes == flag
            if sel.any():
                proj = lane.project(centre[sel])
                xy[sel] = lane.point_at(proj.s)
                yaw[sel] = proj.heading
        return xy, yaw


def _inside_rect(px, py, cx, cy, yaw, half_len, half_wid):
    """Strictly inside a rectangle centred at (cx, cy) turned by yaw; broadcasts."""
    dx = px - cx
    dy = py - cy
    c = np.cos(yaw)
    s = np.sin(yaw)
    u = dx * c + dy * s
    v = -dx * s + dy * c
    return (np.abs(u) < half_len) & (np.abs(v) < half_wid)


def _point_in_ring(px: np.ndarray, py: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """Even-odd test of points against a closed ring (first == last not required)."""
    x1, y1 = ring[:, 0], ring[:, 1]
    x2, y2 = np.roll(x1, -1), np.roll(y1, -1)
    px = px[:, None]
    py = py[:, None]
    crosses = (y1 > py) != (y2 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
    return (crosses & (px < xint)).sum(axis=1) % 2 == 1


def camera_frustum_contains(cam_x, cam_y, cam_z, yaw, px, py, pz) -> np.ndarray:
    """True where the point (px, py, pz) is inside the camera's view frustum (HFOV 1.13 rad, 4:3, pitched
    down 0.2618 rad, 0.02-300 m); broadcasts over cars and points."""
    dx = px - cam_x
    dy = py - cam_y
    dz = pz - cam_z
    c, s = np.cos(yaw), np.sin(yaw)
    fwd = dx * c + dy * s
    left = -dx * s + dy * c
    cp, sp = math.cos(CAMERA_PITCH_RAD), math.sin(CAMERA_PITCH_RAD)
    depth = fwd * cp - dz * sp  # along the optical axis (pitched down)
    up = fwd * sp + dz * cp
    tan_h = math.tan(CAMERA_HFOV_RAD / 2)
    tan_v = tan_h / CAMERA_ASPECT
    return ((depth > CAMERA_NEAR_M) & (depth < CAMERA_FAR_M) & (np.abs(left) <= depth * tan_h)
            & (np.abs(up) <= depth * tan_v))


class ObjectSet:
    """The objects of every car of a simulator: per car `m` boxes with pose and their static params.

    Arrays (car axis first): `xy` (n, m, 2), `yaw` (n, m), `arc` (n, m: centre-line projection in the car's
    driving direction, the param `objects_distance`), `dfc` (n, m), `left` (n, m).
    """

    def __init__(self, race: RaceConfig, track: Track, track_reversed: Track, num_cars: int, rng):
        self.race = race
        self.rng = rng
        self.lanes = (Lanes(track), Lanes(track_reversed))
        self._inner_ring = np.vstack([track.center, track.inner[::-1]])
        self._ccw = (track.is_ccw, track_reversed.is_ccw)
        self.bots = race.num_bot_cars > 0
        m = race.num_bot_cars if self.bots else race.num_obstacles
        self.num_objects = m
        foot = CAR_FOOTPRINT_M if self.bots else BOX_FOOTPRINT_M
        self.half = (0.5 * foot[0], 0.5 * foot[1])
        self.box_size_m = np.array(CAR_FOOTPRINT_M if self.bots else BOX_SIZE_M)
        self.speed = race.bot_car_speed if self.bots else 0.0
        self.lane_s0 = np.zeros((num_cars, m))  # bots: arc length along their lane line at the episode start
        self.rev = np.zeros(num_cars, dtype=np.bool_)
        self.xy = np.zeros((num_cars, m, 2))
        self.yaw = np.zeros((num_cars, m))
        self.arc = np.zeros((num_cars, m))
        self.dfc = np.zeros((num_cars, m))
        self.left = np.zeros((num_cars, m), dtype=np.bool_)
        self.lane = np.zeros((num_cars, m), dtype=np.int64)
        self.order = np.zeros((num_cars, m), dtype=np.int64)  # objects sorted by `arc`
        self._lists: list = [None] * num_cars

    def place(self, idx: np.ndarray, reversed_: np.ndarray) -> None:
        """New layouts for cars `idx` (each in its driving direction `reversed_`)."""
        for i, rev in zip(np.asarray(idx).tolist(), np.asarray(reversed_, dtype=bool).tolist(), strict=True):
            lanes = self.lanes[int(rev)]
            arcs, lane = obstacle_arcs(self.race, lanes.track.length, self.rng)
            xy, yaw = lanes.poses(arcs, lane)
            self.xy[i], self.yaw[i], self.lane[i] = xy, yaw, lane
            self.rev[i] = rev
            if self.bots:
                for flag, line in ((1, lanes.inner), (-1, lanes.outer)):
                    sel = lane == flag
                    if sel.any():
                        self.lane_s0[i, sel] = line.project(xy[sel]).s
            self._measure(i)

    def drive(self, idx, elapsed) -> None:
        """Bot cars of cars `idx` where they are `elapsed` s (per car) after their episode start: each drives its
        lane at `bot_car_speed` (kinematic: it never reacts to the agent)."""
        for i, t in zip(np.asarray(idx).tolist(), np.asarray(elapsed, dtype=np.float64).tolist(), strict=True):
            lanes = self.lanes[int(self.rev[i])]
            for flag, line in ((1, lanes.inner), (-1, lanes.outer)):
                sel = self.lane[i] == flag
                if sel.any():
                    s = self.lane_s0[i, sel] + self.speed * t
                    s = np.mod(s, line.length) if line.closed else np.minimum(s, line.length)
                    self.xy[i, sel] = line.point_at(s)
                    self.yaw[i, sel] = line.heading_at(s)
            self._measure(i)

    def _measure(self, i: int) -> None:
        """The static params of car i's objects at their current poses."""
        rev = int(self.rev[i])
        xy = self.xy[i]
        proj = self.lanes[rev].track.project(xy)
        self.arc[i] = proj.s
        self.dfc[i] = np.abs(proj.lateral)
        # AWS: inside the polygon between centre line and inner border, XOR not ccw (driving direction)
        self.left[i] = _point_in_ring(xy[:, 0], xy[:, 1], self._inner_ring) ^ (not self._ccw[rev])
        self.order[i] = np.argsort(self.arc[i], kind="stable")
        self._lists[i] = (xy.tolist(), self.left[i].tolist(), self.arc[i].tolist(), self.dfc[i].tolist(),
                          self.yaw[i].tolist() if self.bots else [0.0] * self.num_objects)

    def clear_starts(self, idx, reversed_, pts: np.ndarray, yaw: np.ndarray) -> None:
        """Move start poses (centre-line points `pts`, headings `yaw`, in place) that are within 1 m of one of
        the car's objects onto the lane on the other side of that object, as AWS starts a training episode."""
        for j, (i, rev) in enumerate(zip(np.asarray(idx).tolist(), np.asarray(reversed_).tolist(), strict=True)):
            d = np.hypot(*(self.xy[i] - pts[j]).T)
            if d.size == 0 or d.min() >= CLOSEST_OBJ_GAP_M:
                continue
            lanes = self.lanes[int(rev)]
            lane = lanes.outer if self.lane[i, int(np.argmin(d))] == 1 else lanes.inner
            proj = lane.project(pts[j:j + 1])
            pts[j] = lane.point_at(proj.s)[0]
            yaw[j] = proj.heading[0]

    def features_ahead(self, rows, x, y, yaw, s, length: float, out: np.ndarray) -> None:
        """Fill out[j] (2 * FEATURE_OBJECTS columns) for car rows[j] at base pose (x, y, yaw) with centre-line arc
        s: the nearest objects ahead along the lap, in the car's frame (x ahead, y left) divided by 2 m, as the
        centre points of `features`; with fewer objects the list repeats from the nearest."""
        ahead = np.mod(self.arc[rows] - s[:, None], length)
        order = np.argsort(ahead, axis=1, kind="stable")
        pick = order[:, np.arange(FEATURE_OBJECTS) % self.num_objects]  # (k, F)
        dx = self.xy[rows[:, None], pick, 0] - x[:, None]
        dy = self.xy[rows[:, None], pick, 1] - y[:, None]
        c, sn = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        out[:, 0::2] = (dx * c + dy * sn) * 0.5
        out[:, 1::2] = (-dx * sn + dy * c) * 0.5

    def reset_behind(self, i: int, reversed_: bool, mx: float, my: float) -> tuple[float, float, float, float]:
        """AWS's evaluation reset after car i (model point mx, my) hit a box: (x, y, yaw) on the lane opposite
        the nearest box, `RESET_BEHIND_DIST_M` of centre line behind it, and that point's centre-line arc."""
        k = int(np.argmin(np.hypot(self.xy[i, :, 0] - mx, self.xy[i, :, 1] - my)))
        lanes = self.lanes[int(reversed_)]
        t = lanes.track
        s = self.arc[i, k] - RESET_BEHIND_DIST_M
        s = s % t.length if t.closed else max(s, 0.0)
        lane = lanes.outer if self.lane[i, k] == 1 else lanes.inner
        proj = lane.project(t.point_at(s).reshape(1, 2))
        x, y = lane.point_at(proj.s)[0]
        return float(x), float(y), float(proj.heading[0]), float(s)

    def crashed(self, bx, by, yaw, rows=None, car_arc=None, length: float = 0.0) -> np.ndarray:
        """Per car (`rows`, all by default): a corner of the car at base pose (bx, by, yaw) is inside one of its
        objects' footprints. A bot car counts only when it is ahead of the car along the lap (within half a lap of
        centre line from `car_arc`): the car ran into it; a bot that runs into the car from behind is not the
        car's crash (AWS compares the two cars' progress)."""
        hl, hw = 0.5 * CAR_FOOTPRINT_M[0], 0.5 * CAR_FOOTPRINT_M[1]
        c, s = np.cos(yaw), np.sin(yaw)
        ox = np.array([hl, hl, -hl, -hl])
        oy = np.array([hw, -hw, hw, -hw])
        cx = bx[:, None] + ox * c[:, None] - oy * s[:, None]  # (k, 4)
        cy = by[:, None] + ox * s[:, None] + oy * c[:, None]
        rows = np.arange(bx.size) if rows is None else np.asarray(rows)
        inside = _inside_rect(cx[:, :, None], cy[:, :, None], self.xy[rows, None, :, 0], self.xy[rows, None, :, 1],
                              self.yaw[rows, None, :], *self.half).any(axis=1)  # (k, m)
        if self.bots and car_arc is not None:
            inside &= np.mod(self.arc[rows] - car_arc[:, None], length) < 0.5 * length
        return inside.any(axis=1)

    def params_columns(self, idx, model_xy, model_s, base_pose) -> dict:
        """The `objects_*` params columns for cars `idx`: the model point's xy (k, 2) and centre-line arc (k,),
        and the base pose (x, y, yaw) for the camera test."""
        idx = np.asarray(idx)
        arcs = self.arc[idx]
        order = self.order[idx]
        sorted_arcs = np.take_along_axis(arcs, order, axis=1)
        m = self.num_objects
        nxt = (sorted_arcs <= model_s[:, None]).sum(axis=1)  # bisect_right
        prv = np.where(nxt - 1 < 0, m - 1, nxt - 1)
        nxt = np.where(nxt == m, 0, nxt)
        rows = np.arange(idx.size)
        prev_obj = order[rows, prv]
        next_obj = order[rows, nxt]
        in_cam = self.in_camera(idx, next_obj, base_pose)
        lists = [self._lists[i] for i in idx.tolist()]
        return {
            "closest_objects": (prev_obj.tolist(), next_obj.tolist()),
            "objects_location": [[[*p] for p in t[0]] for t in lists],
            "objects_left_of_center": [t[1] for t in lists],
            "objects_distance": [t[2] for t in lists],
            "objects_distance_from_center": [t[3] for t in lists],
            "objects_heading": [t[4] for t in lists],
            "objects_speed": [[float(self.speed)] * m] * idx.size,
            "object_in_camera": in_cam.tolist(),
        }

    def in_camera(self, idx, obj, base_pose) -> np.ndarray:
        """Per car: object `obj` (its centre or a footprint corner, at box height) is in the camera frustum."""
        bx, by, byaw = base_pose
        cam_ahead, cam_z = camera_position()
        camx = bx + cam_ahead * np.cos(byaw)
        camy = by + cam_ahead * np.sin(byaw)
        ox = self.xy[idx, obj, 0]
        oy = self.xy[idx, obj, 1]
        oyaw = self.yaw[idx, obj]
        hl, hw = self.half
        du = np.array([0.0, hl, hl, -hl, -hl])
        dv = np.array([0.0, hw, -hw, hw, -hw])
        c, s = np.cos(oyaw)[:, None], np.sin(oyaw)[:, None]
        px = ox[:, None] + du * c - dv * s
        py = oy[:, None] + du * s + dv * c
        vis = camera_frustum_contains(camx[:, None], camy[:, None], cam_z, byaw[:, None], px, py, OBSTACLE_Z_M)
        return vis.any(axis=1)


def base_from_model_point(mx, my, heading_deg):
    """The base pose (x, y, yaw) behind a measured model point (`MODEL_POINT_AHEAD_M` back along the heading)."""
    yaw = np.radians(heading_deg)
    return mx - MODEL_POINT_AHEAD_M * np.cos(yaw), my - MODEL_POINT_AHEAD_M * np.sin(yaw), yaw
