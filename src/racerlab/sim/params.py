"""The AWS reward params of the simulator's cars (facts §1, with the code's semantics).

`ParamsBuilder` makes one dict per car from the simulator's params table in bulk (columns are turned into Python
lists once, then `racerlab.spec.ParamsMaker` makes the dicts). Calling the reward function on them is
`racerlab.reward`'s.
"""

from __future__ import annotations

import numpy as np

from racerlab.sim import _kernels as K
from racerlab.sim.objects import base_from_model_point
from racerlab.spec import NO_OBJECTS, ParamsMaker


class ParamsBuilder:
    """Builds the AWS reward params dicts for a simulator's cars (keys and order: `racerlab.spec.REWARD_PARAMS`)."""

    _make = ParamsMaker(("all_wheels_on_track", "x", "y", "heading", "distance_from_center", "is_left_of_center",
                         "is_reversed", "progress", "steps", "speed", "steering_angle", "waypoints",
                         "closest_waypoints", "track_width", "projection_distance", "is_offtrack"),
                        parts={"closest_waypoints": 2})

    _OBJECT_KEYS = ("closest_objects", "objects_location", "objects_left_of_center", "objects_distance",
                    "objects_distance_from_center", "objects_heading", "objects_speed", "object_in_camera")
    _make_objects = ParamsMaker((*_make.per_row, "is_crashed", *_OBJECT_KEYS),
                                parts={"closest_waypoints": 2, "closest_objects": 2})

    def __init__(self, sim):
        self.sim = sim
        self._waypoints = (sim.track.waypoints, sim.track_reversed.waypoints)
        self._length = sim.track.length
        self._constants = {"track_length": sim.track.length, "is_crashed": False, **NO_OBJECTS}

    def build(self, idx=None, status=None, actions=None) -> list[dict]:
        """Params for cars `idx` (all by default) from `sim.params`, with the commanded actions."""
        return list(self.each(idx, status, actions))

    def each(self, idx=None, status=None, actions=None):
        """Yield the params dict of each car in `idx` in turn (streaming keeps memory warm for big batches)."""
        sim = self.sim
        idx = np.arange(sim.num_cars) if idx is None else np.asarray(idx)
        c = sim.params[idx].T.tolist()  # the judged pose's measurements, one list per K.M* column
        ctr = sim.ctr[idx].T.tolist()
        st = sim.status[idx] if status is None else np.asarray(status)[idx]
        steer = sim.car[idx, K.CCMD_STEER] if actions is None else actions[0][idx]
        speed = sim.car[idx, K.CCMD_SPEED] if actions is None else actions[1][idx]
        rev = [r != 0 for r in ctr[K.KREV]]
        wps = self._waypoints
        cols = {
            "all_wheels_on_track": [w == 4.0 for w in c[K.MWHEELS]],
            "x": c[K.MX],
            "y": c[K.MY],
            "heading": c[K.MHEADING],
            "distance_from_center": c[K.MDIST],
            "is_left_of_center": [v > 0.5 for v in c[K.MLEFT]],
            "is_reversed": rev,
            "progress": c[K.MPROG],
            "steps": [float(v) for v in ctr[K.KSTEPS]],
            "speed": np.asarray(speed, dtype=np.float64).tolist(),
            "steering_angle": np.asarray(steer, dtype=np.float64).tolist(),
            "track_width": c[K.MWIDTH],
            "waypoints": [wps[r] for r in rev],
            "closest_waypoints": ([int(v) for v in c[K.MWP_PREV]], [int(v) for v in c[K.MWP_NEXT]]),
            "projection_distance": c[K.MS],
            "is_offtrack": (st == K.OFF_TRACK).tolist(),
        }
        # sim_time of the measured pose: the step's start (AWS order) or its end (after_action)
        t = sim.time if sim.after_action else sim.time - sim.dt
        if sim.objects is None:
            return self._make(cols, {**self._constants, "sim_time": t})
        p = sim.params[idx]
        base = base_from_model_point(p[:, K.MX], p[:, K.MY], p[:, K.MHEADING])
        cols.update(sim.objects.params_columns(idx, p[:, K.MX:K.MY + 1], p[:, K.MS], base))
        cols["is_crashed"] = (st == K.CRASHED).tolist()
        return self._make_objects(cols, {"track_length": self._length, "sim_time": t})
