"""Racing lines: minimum-curvature and shortest-path lines, the speed profile the simulator's car can
drive on them, and the theoretical best lap (the limit: the simulator's off-track rule, not the line's margin).

    >>> from racerlab.line import racing_line, theoretical_limit
    >>> line = racing_line("reInvent2019_track", margin=0.1)       # or a Track
    >>> line.lap_time, line.xy, line.speed                           # s, (M, 2), (M,)
    >>> theoretical_limit("reInvent2019_track").lap_time          # the fastest lap the simulator allows

`geometry` holds the curve helpers, `solve` the line solvers, `profile` the speed profile and
`export` the files the `racerlab line` command writes.
"""

from racerlab.line.core import (
    DEFAULT_MARGIN_M,
    RacingLine,
    car_clearance,
    fastest_line,
    min_margin,
    offtrack_overhang,
    racing_line,
    steering_for_curvature,
    theoretical_limit,
)
from racerlab.line.solve import METHODS

__all__ = ["DEFAULT_MARGIN_M", "METHODS", "RacingLine", "car_clearance", "fastest_line", "min_margin",
           "offtrack_overhang", "racing_line",
           "steering_for_curvature", "theoretical_limit"]
