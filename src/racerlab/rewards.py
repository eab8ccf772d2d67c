"""Reward function templates for `racerlab init --reward NAME`.

Each template is an ordinary AWS reward function file in `racerlab/data/rewards/` (the default,
"example", is `data/examples/reward_function.py`). "racing_line" is filled in for a track: the line
`racerlab line` computes (minimum curvature under the car's limits) is written into the file, with
its speeds capped at the model's top action speed, so the file stays self-contained as AWS needs.
"""

from __future__ import annotations

from pathlib import Path

from racerlab.errors import ConfigError

DATA = Path(__file__).resolve().parent / "data"
TEMPLATES = {
    "example": DATA / "examples" / "reward_function.py",
    "centre_line": DATA / "rewards" / "centre_line.py",
    "progress": DATA / "rewards" / "progress.py",
    "racing_line": DATA / "rewards" / "racing_line.py",
}
LINE_POINT_SPACING_M = 0.2  # every other point of the solver's ~0.1 m line: half the search per step


def reward_source(name: str, track=None, max_speed: float | None = None, car=None) -> str:
    """The text of template `name`; "racing_line" needs the track (name, path or Track) and takes the car whose
    speeds it writes (a simulator's name or a `CarParams`; default the droa car)."""
    if name not in TEMPLATES:
        raise ConfigError(f"reward template {name!r} does not exist; choose one of {', '.join(TEMPLATES)}")
    text = TEMPLATES[name].read_text()
    if name != "racing_line":
        return text
    if track is None:
        raise ConfigError("reward template 'racing_line' needs the model's track; give --track")
    from racerlab.line import racing_line

    line = racing_line(track, car=car)
    step = max(1, int(round(LINE_POINT_SPACING_M / max(line.length / len(line.xy), 1e-9))))
    speeds = line.speed if max_speed is None else [min(v, max_speed) for v in line.speed]
    rows = ",\n".join(f"    [{x:.4f}, {y:.4f}, {v:.3f}]"
                      for (x, y), v in list(zip(line.xy, speeds, strict=True))[::step])
    return (text.replace("__TRACK__", line.track_name)
            .replace("RACING_LINE = []", f"RACING_LINE = [  # {line.method}, theoretical lap {line.lap_time:.3f} s "
                                         f"({line.car.simulator} car)\n"
                                         f"{rows},\n]", 1))


def top_speed(actions) -> float:
    """The action space's highest speed, m/s (discrete: the fastest action; continuous: the range's top)."""
    speeds = getattr(actions, "speed", None)
    return float(max(speeds)) if speeds is not None else float(actions.speed_high)


def write_reward(folder_reward_path, name: str, track=None, max_speed: float | None = None, car=None) -> Path:
    path = Path(folder_reward_path)
    path.write_text(reward_source(name, track, max_speed, car))
    return path
