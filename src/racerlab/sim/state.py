"""The simulator's public, named view of its cars: `CarState`, the episode `Status` codes, trace columns.

The simulator keeps its state in integer-column tables for the compiled step (`_kernels`); code outside
`racerlab.sim` reads it through these names instead:

    >>> s = sim.state                  # the cars now (the pose the next observation shows)
    >>> s.x, s.speed, s.progress       # numpy arrays, one value per car
    >>> sim.judged.progress            # what the last step's rules and reward judged (the simtrace row)
    >>> codes == Status.LAP_COMPLETE
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from racerlab.sim import _kernels as K

# the simtrace columns the simulator knows (`Simulator.trace_columns`); the caller adds episode, action,
# reward, done, episode_status, pause_duration, obstacle_crash_counter and wall_clock
TRACE_COLUMNS = ("steps", "X", "Y", "yaw", "steer", "throttle", "all_wheels_on_track", "progress",
                 "closest_waypoint", "track_len", "tstamp")


class Status(IntEnum):
    """Episode status codes as `Simulator.step` returns them; `STATUS_NAMES[code]` is the AWS name."""

    IN_PROGRESS = K.IN_PROGRESS
    LAP_COMPLETE = K.LAP_COMPLETE
    CRASHED = K.CRASHED
    OFF_TRACK = K.OFF_TRACK
    IMMOBILIZED = K.IMMOBILIZED
    REVERSED = K.REVERSED
    PREPARE = K.STATUS_PREPARE
    PAUSE = K.PAUSE
    TIME_UP = K.TIME_UP

    @property
    def aws_name(self) -> str:
        """The status as AWS logs it ("lap_complete", "off_track", ...)."""
        return K.STATUS_NAMES[self.value]


class CarState:
    """Named per-car arrays over the simulator's tables, car axis first.

    Fields that are plain columns (pose, speeds, commands, counters, measurements) are views: reading
    them costs nothing and writing one changes the simulator (tests set speeds that way). Derived
    fields (`reversed`, `is_left_of_center`, `wheels_on_track`, `all_wheels_on_track`,
    `closest_waypoint(s)`) are computed copies.

    The measured fields (model point, track position, progress, heading) come from one measurement
    table: the current pose's for `Simulator.state`, the judged pose's for `Simulator.judged`.
    """

    __slots__ = ("_car", "_ctr", "_meas")

    def __init__(self, car: np.ndarray, ctr: np.ndarray, meas: np.ndarray):
        self._car, self._ctr, self._meas = car, ctr, meas

    def __len__(self) -> int:
        return self._car.shape[0]

    # ---- the car (base link = rear-axle centre) --------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        """Base-link x, m."""
        return self._car[:, K.CX]

    @property
    def y(self) -> np.ndarray:
        """Base-link y, m."""
        return self._car[:, K.CY]

    @property
    def yaw(self) -> np.ndarray:
        """Heading of the car, rad."""
        return self._car[:, K.CYAW]

    @property
    def speed(self) -> np.ndarray:
        """Actual ground speed, m/s (the reward param `speed` is the commanded one)."""
        return self._car[:, K.CV]

    @property
    def steering(self) -> np.ndarray:
        """Actual front-wheel angle, rad (it lags the command)."""
        return self._car[:, K.CSTEER]

    @property
    def slip(self) -> np.ndarray:
        """Body slip angle, rad."""
        return self._car[:, K.CBETA]

    @property
    def command_steering(self) -> np.ndarray:
        """Commanded steering of the last step, degrees (0 on the prepare step)."""
        return self._car[:, K.CCMD_STEER]

    @property
    def command_speed(self) -> np.ndarray:
        """Commanded speed of the last step, m/s (0 on the prepare step)."""
        return self._car[:, K.CCMD_SPEED]

    @property
    def start(self) -> np.ndarray:
        """Where the episode started, as a fraction of the lap in the driving direction."""
        return self._car[:, K.CSTART]

    # ---- the episode ---------------------------------------------------------------------------
    @property
    def steps(self) -> np.ndarray:
        """Steps of the episode so far (the prepare step included)."""
        return self._ctr[:, K.KSTEPS]

    @property
    def status(self) -> np.ndarray:
        """`Status` code of the last step."""
        return self._ctr[:, K.KSTATUS]

    @property
    def reversed(self) -> np.ndarray:
        """True where the car drives the track the other way."""
        return self._ctr[:, K.KREV].astype(bool)

    # ---- the measured pose ---------------------------------------------------------------------
    @property
    def model_x(self) -> np.ndarray:
        """x of the point AWS reports (`params["x"]`, the simtrace X), m."""
        return self._meas[:, K.MX]

    @property
    def model_y(self) -> np.ndarray:
        return self._meas[:, K.MY]

    @property
    def heading(self) -> np.ndarray:
        """Heading in degrees (`params["heading"]`)."""
        return self._meas[:, K.MHEADING]

    @property
    def progress(self) -> np.ndarray:
        """Progress of the lap from the episode start, %."""
        return self._meas[:, K.MPROG]

    @property
    def projection_distance(self) -> np.ndarray:
        """Arc length of the centre line at the model point, m."""
        return self._meas[:, K.MS]

    @property
    def distance_from_center(self) -> np.ndarray:
        return self._meas[:, K.MDIST]

    @property
    def lateral_offset(self) -> np.ndarray:
        """Signed distance from the centre line, m (left of the driving direction positive)."""
        return self._meas[:, K.MLAT]

    @property
    def track_heading(self) -> np.ndarray:
        """Direction of the centre-line segment the car is on, rad."""
        return self._meas[:, K.MTHEAD]

    @property
    def track_width(self) -> np.ndarray:
        return self._meas[:, K.MWIDTH]

    @property
    def is_left_of_center(self) -> np.ndarray:
        return self._meas[:, K.MLEFT] > 0.5

    @property
    def wheels_on_track(self) -> np.ndarray:
        """How many of the four wheels are on the road."""
        return self._meas[:, K.MWHEELS].astype(np.int64)

    @property
    def all_wheels_on_track(self) -> np.ndarray:
        return self._meas[:, K.MWHEELS] == 4

    @property
    def closest_waypoint(self) -> np.ndarray:
        """The waypoint nearest the model point (the simtrace's closest_waypoint)."""
        return self._meas[:, K.MCLOSEST].astype(np.int64)

    @property
    def closest_waypoints(self) -> np.ndarray:
        """(n, 2) previous and next waypoint (`params["closest_waypoints"]`)."""
        return self._meas[:, [K.MWP_PREV, K.MWP_NEXT]].astype(np.int64)
