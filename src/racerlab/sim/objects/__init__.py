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

Bot cars (`BotCarsCtrl`, next_capabilities §A.2) start like boxes (min distance in metres, their own
`randomize_bot_car_locations`) and drive their lane keyed by centre-line distance, changing lanes every
U(lower, upper) s over `lane_change_distance` m; they pause `penalty_seconds` after one ran into the car. In a
head-to-model race each car's one object is the other car of its pair. docs/objects.md has the details and the
differences from AWS.

Crash rule: `objects.crash` (a corner of the car's footprint strictly inside an object's footprint).

The package holds one subject per module, and `ObjectSet` (`objects.core`) gathers their methods over its arrays:
`placement` (the race settings, where boxes and bots stand, the evaluation's reset behind a box), `starts`
(a start near a box moves to the other lane), `motion` (the bot cars' driving, the head-to-model pairs), `crash`
(the crash rule) and `sensing` (the objects' params, the `features` observation's objects, the camera test).
"""

from __future__ import annotations

from racerlab.sim.objects.core import ObjectSet, race_layout
from racerlab.sim.objects.crash import BOX_FOOTPRINT_M, CAR_FOOTPRINT_M, base_from_model_point
from racerlab.sim.objects.placement import END_MARGIN_M, RESET_BEHIND_DIST_M, Lanes, as_race, obstacle_arcs
from racerlab.sim.objects.sensing import (
    BOX_SIZE_M,
    CAMERA,
    CAMERA_ASPECT,
    CAMERA_FAR_M,
    CAMERA_HFOV_RAD,
    CAMERA_NEAR_M,
    CAMERA_PITCH_RAD,
    FEATURE_OBJECTS,
    OBSTACLE_Z_M,
    RING_BAND_M,
)
from racerlab.sim.objects.starts import CLOSEST_OBJ_GAP_M, MOVED_STARTS_KEPT, MovedStarts
from racerlab.spec import RaceConfig

__all__ = ["BOX_FOOTPRINT_M", "BOX_SIZE_M", "CAMERA", "CAMERA_ASPECT", "CAMERA_FAR_M", "CAMERA_HFOV_RAD",
           "CAMERA_NEAR_M", "CAMERA_PITCH_RAD", "CAR_FOOTPRINT_M", "CLOSEST_OBJ_GAP_M", "END_MARGIN_M",
           "FEATURE_OBJECTS", "MOVED_STARTS_KEPT", "OBSTACLE_Z_M", "RESET_BEHIND_DIST_M", "RING_BAND_M", "Lanes",
           "MovedStarts", "ObjectSet", "RaceConfig", "as_race", "base_from_model_point", "obstacle_arcs",
           "race_layout"]
