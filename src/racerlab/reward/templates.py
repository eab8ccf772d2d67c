"""Reward function files racerlab writes: the example a new model starts from (one per race type) and the
templates of `racerlab init --reward NAME`.

Each template is an ordinary AWS reward function file in `racerlab/data/rewards/` (the default, "example", is
`data/examples/reward_function.py`). "racing_line" is filled in with a racing line of the model's track, computed
by the caller: the limit's kind of path (`racerlab.line.fastest_line`, the fastest of the paths
`theoretical_limit` tries) kept `LINE_MARGIN_M` from the borders unless the racer chooses another margin
(`racerlab init --line-margin`). Its points are written into the file with the speeds capped at the model's top
action speed, so the file stays self-contained as AWS needs.
"""

from __future__ import annotations

import re
from pathlib import Path

from racerlab.errors import ConfigError

DATA = Path(__file__).resolve().parent.parent / "data"
EXAMPLE_REWARD = DATA / "examples" / "reward_function.py"
OBJECT_AVOIDANCE_REWARD = DATA / "examples" / "reward_function_object_avoidance.py"
EXAMPLE_REWARDS = {"time_trial": EXAMPLE_REWARD, "object_avoidance": OBJECT_AVOIDANCE_REWARD,
                   "head_to_bot": OBJECT_AVOIDANCE_REWARD, "head_to_model": OBJECT_AVOIDANCE_REWARD}
TEMPLATES = {
    "example": EXAMPLE_REWARD,
    "centre_line": DATA / "rewards" / "centre_line.py",
    "progress": DATA / "rewards" / "progress.py",
    "racing_line": DATA / "rewards" / "racing_line.py",
    "pace": DATA / "rewards" / "pace.py",  # ground gained along any track per step: the generalist's teacher's
}
NEEDS_LINE = ("racing_line",)
# The racing_line template's margin between the wheels and the borders, m. Negative: the wheels hang over the
# border, as fast laps do; the off-track rule (all four wheels off) leaves -0.23 m on the droa car, so -0.1 keeps
# 0.13 m of slack. On reInvent2019_track the line's own lap is 6.133 s (the limit 5.933 s; the former line, 0.1 m
# inside, 6.667 s, held the learner at 6.467-6.667 s: docs/learner.md).
LINE_MARGIN_M = -0.1
LINE_POINT_SPACING_M = 0.2  # every other point of the solver's ~0.1 m line: half the search per step


def reward_source(name: str, line=None, max_speed: float | None = None) -> str:
    """The text of template `name`; "racing_line" needs `line` (a `racerlab.line.RacingLine`)."""
    if name not in TEMPLATES:
        raise ConfigError(f"reward template {name!r} does not exist; choose one of {', '.join(TEMPLATES)}")
    text = TEMPLATES[name].read_text()
    if name not in NEEDS_LINE:
        return text
    if line is None:
        raise ConfigError(f"reward template {name!r} needs the model's track; give --track")
    step = max(1, int(round(LINE_POINT_SPACING_M / max(line.length / len(line.xy), 1e-9))))
    speeds = line.speed if max_speed is None else [min(v, max_speed) for v in line.speed]
    rows = ",\n".join(f"    [{x:.4f}, {y:.4f}, {v:.3f}]"
                      for (x, y), v in list(zip(line.xy, speeds, strict=True))[::step])
    return (text.replace("__TRACK__", line.track_name)
            .replace("RACING_LINE = []", f"RACING_LINE = [  # {line.method} line, margin {line.margin_m:g} m, its lap "
                                         f"{line.lap_time:.3f} s ({line.car.simulator} car)\n"
                                         f"{rows},\n]", 1))


def line_lap(source: str) -> float | None:
    """The lap time (s) of the racing line a racing_line reward file's text holds, as `reward_source` wrote it in
    the line's header; None for another reward (or a header edited away)."""
    found = re.search(r"RACING_LINE = \[  # .*?, its lap ([0-9.]+) s", source)
    return float(found.group(1)) if found else None
