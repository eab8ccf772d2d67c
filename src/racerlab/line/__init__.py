"""Racing lines: minimum-curvature and shortest-path lines, the speed profile the simulator's car can
drive on them, and the theoretical best lap.

    >>> from racerlab.line import racing_line
    >>> line = racing_line("reInvent2019_track", margin=0.1)       # or a Track
    >>> line.lap_time, line.xy, line.speed                           # s, (M, 2), (M,)

`geometry` holds the curve helpers, `solve` the line solvers, `profile` the speed profile and
`export` the files the `racerlab line` command writes.
"""

from racerlab.line.core import DEFAULT_MARGIN_M, RacingLine, car_clearance, racing_line, steering_for_curvature
from racerlab.line.solve import METHODS

__all__ = ["DEFAULT_MARGIN_M", "METHODS", "RacingLine", "car_clearance", "racing_line", "steering_for_curvature"]
