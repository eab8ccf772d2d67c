"""Hand-written samples of every DeepRacer step-log variant, from the format facts (facts §7).

Each episode is three rows: prepare, in_progress, then off_track (episode 0) or lap_complete (others).
Values are written by hand so that the tests check parsing against text, not against our writer.
"""

from __future__ import annotations

import gzip
import io
import tarfile
from pathlib import Path

HEADER_19 = ("episode,steps,X,Y,yaw,steer,throttle,action,reward,done,all_wheels_on_track,progress,"
             "closest_waypoint,track_len,tstamp,episode_status,pause_duration,obstacle_crash_counter,wall_clock")
HEADER_17 = ("episode,steps,X,Y,yaw,steer,throttle,action,reward,done,all_wheels_on_track,progress,"
             "closest_waypoint,track_len,tstamp,episode_status,pause_duration")


def rows_19(episode: int, action: str = "3", x0: float = 3.0598) -> list[str]:
    """Three 19-field rows of one episode (no prefix)."""
    last = "off_track" if episode == 0 else "lap_complete"
    on = "False" if episode == 0 else "True"
    return [
        f"{episode},1,{x0:.4f},0.6886,-132.2484,-30.00,0.50,{action},0.0000,False,True,0.7046,1,23.12,36.597,"
        "prepare,0.00,0,1700000000.1000",
        f"{episode},2,{x0 + 0.01:.4f},0.6786,-131.0000,15.00,1.50,{action},1.2500,False,True,1.0000,2,23.12,36.664,"
        "in_progress,0.00,0,1700000000.1667",
        f"{episode},3,{x0 + 0.02:.4f},0.6686,-130.5000,0.00,2.00,{action},0.5000,True,{on},1.5000,2,23.12,36.731,"
        f"{last},0.00,0,1700000000.2333",
    ]


def rows(fields: int, episode: int, action: str = "3") -> list[str]:
    """Rows with `fields` fields: 19 cut down to 18 (obstacle counter kept), 17, 16 or 15."""
    cut = fields + action.count(",")  # an old "[a, b]" action spans two comma-separated parts
    return [",".join(r.split(",")[:cut]) for r in rows_19(episode, action)]


def radian_rows(episode: int) -> list[str]:
    """2019-style 15-field rows: yaw and steer in radians, tstamp a wall clock."""
    return [
        f"{episode},0,3.0598,0.6886,-2.3082,-0.5236,0.50,0,0.0000,False,True,0.7046,1,23.12,1556000000.101",
        f"{episode},1,3.0698,0.6786,-2.2865,0.2618,1.50,4,1.2500,False,True,1.0000,2,23.12,1556000000.168",
        f"{episode},2,3.0798,0.6686,-2.2777,0.0000,2.00,2,0.5000,True,True,1.5000,2,23.12,1556000000.235",
    ]


def log_text(lines: list[str], prefix: str = "", hyper: dict | None = None) -> str:
    """A robomaker-style log: noise lines, an optional hyperparameter block, then SIM_TRACE_LOG lines."""
    out = ["INFO:root:starting simulation", " * /WORLD_NAME: reInvent2019_track"]
    if hyper is not None:
        out.append(f"{prefix}Using the following hyper-parameters")
        out.append(prefix + "{")
        items = list(hyper.items())
        for i, (k, v) in enumerate(items):
            out.append(f'{prefix}  "{k}": {v}{"," if i < len(items) - 1 else ""}')
        out.append(prefix + "}")
    for line in lines:
        out.append(f"{prefix}SIM_TRACE_LOG:{line}")
        out.append(f"{prefix}Training> Name=main_level/agent, Worker=0, Episode=1")
    return "\n".join(out) + "\n"


def write(path: Path, text: str | bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gz" and not path.name.endswith(".tar.gz"):
        path.write_bytes(gzip.compress(text.encode() if isinstance(text, str) else text))
    else:
        path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


def csv_text(episodes: list[int], header: str = HEADER_19, fields: int = 19, action: str = "3") -> str:
    body = [r for e in episodes for r in rows(fields, e, action)]
    return header + "\n" + "\n".join(body) + "\n"


def tar_gz(path: Path, members: dict[str, str]) -> Path:
    """A `.tar.gz` holding `members` (relative name -> text)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for name, text in members.items():
            data = text.encode()
            info = tarfile.TarInfo(name)
            info.size = len(data)
            info.mtime = 1700000000
            tar.addfile(info, io.BytesIO(data))
    path.write_bytes(buf.getvalue())
    return path
