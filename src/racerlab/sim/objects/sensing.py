"""What the car senses of the objects: `Sensing`, the part of `ObjectSet` that measures the objects (centre-line
arc and distance, left of centre as AWS has it) into the `objects_*` reward params, the `features` observation's
nearest objects ahead, and the camera frustum the `object_in_camera` param tests (`CAMERA`)."""

from __future__ import annotations

import functools
import math

import numpy as np

from racerlab.sim import _kernels as K
from racerlab.sim import _object_kernels as OK
from racerlab.sim.sensors.geometry import AWS_CAMERA_HEIGHT_M, CAMERA_HFOV_RAD, CAMERA_PITCH_RAD, camera_position
from racerlab.track.kernels import build_road_index

BOX_SIZE_M = (0.40, 0.30)  # the box model (along the lane, across): what the lidar and camera see
OBSTACLE_Z_M = 0.1
FEATURE_OBJECTS = 2  # the `features` observation gains the nearest objects ahead, (x ahead, y left) / 2 m each
CAMERA_ASPECT = 4 / 3  # 640 x 480
CAMERA_FAR_M = 300.0
CAMERA_NEAR_M = 0.02
RING_BAND_M = 0.05  # band height of the index of the centre/inner-border polygon's edges (objects_left_of_center)


def _camera_constants() -> np.ndarray:
    """The camera frustum as `_object_kernels.closest_and_in_camera` takes it (HFOV 1.13 rad, 4:3, pitched down
    0.2618 rad, 0.02-300 m; the camera's place on the car, at the height the AWS look puts it; objects seen at
    OBSTACLE_Z_M)."""
    cam_ahead, cam_z = camera_position()[0], AWS_CAMERA_HEIGHT_M
    tan_h = math.tan(CAMERA_HFOV_RAD / 2)
    return np.array([cam_ahead, cam_z, OBSTACLE_Z_M, math.cos(CAMERA_PITCH_RAD), math.sin(CAMERA_PITCH_RAD), tan_h,
                     tan_h / CAMERA_ASPECT, CAMERA_NEAR_M, CAMERA_FAR_M])


CAMERA = _camera_constants()


class Sensing:
    """`ObjectSet`'s measurements: the objects' params at their poses (`_measure`, compiled), as lists for the
    params dicts, the camera test, and the objects ahead for the `features` observation."""

    @functools.cached_property
    def _ring(self) -> np.ndarray:
        """The polygon between centre line and inner border (AWS's test for `objects_left_of_center`)."""
        track = self.lanes[0].track
        return np.vstack([track.center, track.inner[::-1]])

    @functools.cached_property
    def _geometry(self) -> tuple:
        """The track arrays `_object_kernels.measure` takes: both directions' centre lines (points, segment
        lengths, arc lengths), the polygon between centre line and inner border as edges by horizontal band, and
        each direction's counter-clockwise flag."""
        tracks = [lanes.track for lanes in self.lanes]
        ring = self._ring
        edges = np.column_stack([ring, np.roll(ring, -1, axis=0)])
        edges = np.ascontiguousarray(edges[edges[:, 1] != edges[:, 3]])  # a level edge is never crossed
        return (np.stack([t.center for t in tracks]), np.stack([t.segment_lengths for t in tracks]),
                np.stack([t.waypoint_s for t in tracks]), tracks[0].closed, edges,
                *build_road_index(edges, RING_BAND_M), np.array(self._ccw))

    def _measure(self, rows) -> None:
        """The static params of the objects of cars `rows` (an index, or an array of them) at their current poses
        in one compiled pass: centre-line arc and distance of their projection in the car's driving direction, left
        of centre as AWS has it (inside the polygon between centre line and inner border, XOR not counter-clockwise
        in the driving direction) and the order by arc."""
        rows = np.atleast_1d(np.asarray(rows, dtype=np.int64))
        OK.measure(rows, self.rev, self.xy, *self._geometry, self._hint, self.arc, self.dfc, self.left, self.order)
        if not (self.bots or self.racers):  # boxes keep their params lists between resets
            for i in rows.tolist():
                self._lists[i] = None

    def _params_lists(self, idx: np.ndarray) -> tuple[list, ...]:
        """The per-object params of cars `idx` as columns of lists, one list per car: location, left of centre,
        distance, distance from centre, heading (AWS fills it for bots only). Moving objects' lists are made for
        the batch at once; boxes make theirs once per layout (they stand still between resets) and the locations
        are copied (the params dicts own their lists)."""
        if self.bots or self.racers:
            heading = self.yaw[idx].tolist() if self.bots else [[0.0] * self.num_objects for _ in range(idx.size)]
            return (self.xy[idx].tolist(), self.left[idx].tolist(), self.arc[idx].tolist(), self.dfc[idx].tolist(),
                    heading)
        cars = []
        for i in idx.tolist():
            if self._lists[i] is None:
                self._lists[i] = (self.xy[i].tolist(), self.left[i].tolist(), self.arc[i].tolist(),
                                  self.dfc[i].tolist(), [0.0] * self.num_objects)
            cars.append(self._lists[i])
        return ([[[*p] for p in t[0]] for t in cars], *([t[k] for t in cars] for k in range(1, 5)))

    def features_ahead(self, rows, car: np.ndarray, meas: np.ndarray, length: float, out: np.ndarray,
                       column: int) -> None:
        """Fill out[i, column:column + 2 * FEATURE_OBJECTS] for each car i of `rows`, at its base pose and centre-line
        arc in the simulator's arrays `car` and `meas`: its nearest objects ahead along the lap, in the car's frame
        (x ahead, y left) divided by 2 m, as the centre points of `features`; with fewer objects the list repeats
        from the nearest."""
        OK.features_ahead(np.asarray(rows, dtype=np.int64), car, meas, K.CX, K.CY, K.CYAW, K.MS, float(length),
                          self.arc, self.xy, out, column, FEATURE_OBJECTS)


    def params_columns(self, idx, model_xy, model_s, base_pose) -> dict:
        """The `objects_*` params columns for cars `idx`: the model point's xy (k, 2) and centre-line arc (k,),
        and the base pose (x, y, yaw) for the camera test (the next object's centre or a footprint corner, at box
        height, inside the camera frustum)."""
        idx = np.asarray(idx, dtype=np.int64)
        prev_obj = np.empty(idx.size, dtype=np.int64)
        next_obj = np.empty(idx.size, dtype=np.int64)
        in_cam = np.empty(idx.size, dtype=np.bool_)
        bx, by, byaw = (np.asarray(v, dtype=np.float64) for v in base_pose)
        OK.closest_and_in_camera(idx, np.asarray(model_s, dtype=np.float64), bx, by, byaw, self.arc, self.order,
                                 self.xy, self.yaw, *self.half, CAMERA, prev_obj, next_obj, in_cam)
        location, left, distance, dfc, heading = self._params_lists(idx)
        return {
            "closest_objects": (prev_obj.tolist(), next_obj.tolist()),
            "objects_location": location,
            "objects_left_of_center": left,
            "objects_distance": distance,
            "objects_distance_from_center": dfc,
            "objects_heading": heading,
            "objects_speed": [[float(self.speed)] * self.num_objects] * idx.size,
            "object_in_camera": in_cam.tolist(),
        }
