"""A start near a box moves to the other lane, as AWS starts a training episode (`rollout_agent_ctrl`):
`StartRule`, the part of `ObjectSet` that moves them, and `MovedStarts`, the moved poses remembered by start point
(training restarts from the same few points over and over), with their compiled look-up."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

CLOSEST_OBJ_GAP_M = 1.0  # a start this near an object moves to the other lane (rollout_agent_ctrl)
MOVED_STARTS_KEPT = 4096  # moved start poses remembered (the cache starts afresh when full)


class StartRule:
    """`ObjectSet`'s start rule: start poses within `CLOSEST_OBJ_GAP_M` of one of a car's objects move onto the lane
    on the other side of it."""

    def clear_starts(self, idx, reversed_, pts: np.ndarray, yaw: np.ndarray) -> None:
        """Move start poses (centre-line points `pts`, headings `yaw`, in place) that are within 1 m of one of
        the car's objects onto the lane on the other side of that object, as AWS starts a training episode."""
        if self.num_objects == 0 or len(idx) == 0:
            return
        # where a start moves depends on the track alone (the start point, direction and lane): each is worked
        # out once, as training restarts from the same few points over and over; one compiled pass looks them up
        idx = np.asarray(idx, dtype=np.int64)
        revs = np.asarray(reversed_, dtype=np.bool_)
        cache = self._moved_starts
        found = cache.apply(idx, revs, self.xy, self.lane, pts, yaw)
        if found is None:  # (most resets)
            return
        new, box_lane = found
        moved_pts, moved_yaw = self._moved(revs[new], box_lane, pts[new], yaw[new])
        cache.add(revs[new], box_lane, pts[new], moved_pts, moved_yaw)
        pts[new], yaw[new] = moved_pts, moved_yaw

    def _moved(self, revs, box_lane, pts, yaw) -> tuple[np.ndarray, np.ndarray]:
        """Start points `pts` (k, 2) with headings `yaw` moved onto the lane on the other side of their box (in
        driving direction `revs`, the box on lane `box_lane`): the nearest point of that lane and its heading."""
        pts, yaw = pts.copy(), yaw.copy()
        for rev in (False, True):
            lanes = self.lanes[int(rev)]
            for flag, lane in ((1, lanes.outer), (-1, lanes.inner)):  # the lane on the box's other side
                sel = (revs == rev) & (box_lane == flag)
                if sel.any():
                    proj = lane.project(pts[sel])
                    pts[sel] = lane.point_at(proj.s).reshape(-1, 2)
                    yaw[sel] = proj.heading
        return pts, yaw


@njit(cache=True)
def _nearest_object(rows, oxy, pts):
    """(distance, index) of the object of car rows[j] nearest to point pts[j] (the first of equals)."""
    dist = np.empty(rows.size)
    nearest = np.zeros(rows.size, dtype=np.int64)
    for j in range(rows.size):
        dist[j] = np.inf
        for q in range(oxy.shape[1]):
            d = math.hypot(oxy[rows[j], q, 0] - pts[j, 0], oxy[rows[j], q, 1] - pts[j, 1])
            if d < dist[j]:
                dist[j] = d
                nearest[j] = q
    return dist, nearest


class MovedStarts:
    """Start poses moved away from a box, remembered by (driving direction, the box's lane, start point): an open
    hash table in arrays (up to `MOVED_STARTS_KEPT` entries; it starts afresh when full) that `_apply_moved` reads
    in one compiled pass."""

    def __init__(self):
        size = 2 * MOVED_STARTS_KEPT  # a power of two, never more than half full
        self.keys = np.zeros((size, 3))  # (2 * reversed + (lane == 1), x, y)
        self.values = np.zeros((size, 3))  # moved (x, y, yaw)
        self.used = np.zeros(size, dtype=np.bool_)
        self.count = 0
        self._missing = np.empty((0, 2), dtype=np.int64)

    def apply(self, idx, revs, oxy, lane, pts, yaw) -> tuple[np.ndarray, np.ndarray] | None:
        """Starts `pts`, `yaw` (of cars idx, in directions revs) within 1 m of one of the car's objects (`oxy`,
        on `lane`) take their remembered moved pose, in place; returns the rows of those not remembered yet and
        the lanes of their boxes, or None when there are none."""
        if self._missing.shape[0] < idx.size:
            self._missing = np.empty((idx.size, 2), dtype=np.int64)
        n = _apply_moved(idx, revs, oxy, lane, pts, yaw, CLOSEST_OBJ_GAP_M, self.keys, self.values, self.used,
                         self._missing)
        return (self._missing[:n, 0].copy(), self._missing[:n, 1].copy()) if n else None

    def add(self, revs, box_lane, pts, moved_pts, moved_yaw) -> None:
        """Remember the moved poses of starts `pts` (directions revs, next to a box on box_lane)."""
        if self.count + revs.size > MOVED_STARTS_KEPT:
            self.used[:] = False
            self.count = 0
        self.count += _remember_moved(revs, box_lane, pts, np.column_stack([moved_pts, moved_yaw]), self.keys,
                                      self.values, self.used)


@njit(cache=True, inline="always")
def _moved_slot(code, x, y, keys, used):
    """The slot of key (code, x, y) in the open hash table (keys, used): where it is, or the free slot where it
    goes; and whether it is there."""
    mask = used.size - 1
    h = (np.int64(x * 1e4) * 73856093) ^ (np.int64(y * 1e4) * 19349663) ^ (np.int64(code) * 83492791)
    s = h & mask
    while used[s] and not (keys[s, 0] == code and keys[s, 1] == x and keys[s, 2] == y):
        s = (s + 1) & mask
    return s, used[s]


@njit(cache=True)
def _apply_moved(idx, revs, oxy, lane, pts, yaw, gap, keys, values, used, missing):
    """`MovedStarts.apply`: the remembered moved poses of the starts within `gap` of an object, in place; the
    (row, box lane) of those not remembered go to `missing`; returns their number."""
    dist, nearest = _nearest_object(idx, oxy, pts)
    n = 0
    for j in range(idx.size):
        if dist[j] < gap:
            flag = lane[idx[j], nearest[j]]
            s, found = _moved_slot(2.0 * revs[j] + (flag == 1), pts[j, 0], pts[j, 1], keys, used)
            if found:
                pts[j, 0] = values[s, 0]
                pts[j, 1] = values[s, 1]
                yaw[j] = values[s, 2]
            else:
                missing[n, 0] = j
                missing[n, 1] = flag
                n += 1
    return n


@njit(cache=True)
def _remember_moved(revs, box_lane, pts, moved, keys, values, used):
    """Put the moved poses (k, 3) of starts `pts` in the table; returns the number of new keys."""
    added = 0
    for j in range(revs.size):
        code = 2.0 * revs[j] + (box_lane[j] == 1)
        s, found = _moved_slot(code, pts[j, 0], pts[j, 1], keys, used)
        keys[s, 0] = code
        keys[s, 1] = pts[j, 0]
        keys[s, 2] = pts[j, 1]
        values[s] = moved[j]
        used[s] = True
        added += not found
    return added
