"""Live data for the browser, as server-sent events.

- `metric_events`: a model's `metrics/metrics.jsonl` (one line per training iteration, written by the
  trainer right after the iteration's checkpoint): all lines on connect, then each new line as soon as
  it lands (the file's size is looked at every `POLL_S`), plus the model's state when it changes.
- `live_view`: the cars of the newest complete training iteration, replayed from its simtrace at the
  simulator's 15 steps per second, and for one car what its model sees (`model_sees`): the 160×120 camera
  frame and/or the 64 lidar ranges rendered at its logged pose; nothing for a features model. Positions go out
  10 times a second, the camera 3 times: about 40 kB/s.

Nothing runs for a browser that is not connected: the work is done inside the generators.
"""

from __future__ import annotations

import asyncio
import base64
import json
import math
import time
from pathlib import Path

import numpy as np

from racerlab import logs
from racerlab.spec import MODEL_POINT_AHEAD_M, STEPS_PER_SECOND

POLL_S = 0.2
HEARTBEAT_S = 15.0
VIEW_HZ = 10
CAMERA_EVERY = 3  # one camera frame per this many position frames
MAX_VIEW_CARS = 32
CHART_KEYS = ("iteration", "episodes", "time", "charts/mean_reward", "charts/completion", "losses/entropy",
              "eval/mean_progress", "eval/best_lap", "best/lap_time", "best/lap_iteration", "charts/env_steps_per_s")
TEXT_KEYS = ("best/checkpoint",)  # for the model's header line


def sse(event: str, data) -> str:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'), allow_nan=False)}\n\n"


def _chart_point(entry: dict) -> dict:
    out = {}
    for k in CHART_KEYS:
        v = entry.get(k)
        out[k] = v if isinstance(v, int | float) and math.isfinite(v) else None
    for k in TEXT_KEYS:
        out[k] = entry.get(k) if isinstance(entry.get(k), str) else None
    return out


def _read_lines(path: Path, offset: int) -> tuple[list[dict], int]:
    """Chart points of the complete lines after byte `offset`, and the offset after the last complete one."""
    entries, end = logs.follow_metrics_jsonl(path, offset)
    return [_chart_point(e) for e in entries], end


async def metric_events(workspace, name: str, is_disconnected, poll_s: float = POLL_S):
    path = logs.metrics_jsonl_path(workspace.folder(name).path)
    points, offset = _read_lines(path, 0)
    state = workspace.state(name)
    yield sse("history", {"points": points, "state": state})
    last_beat = time.monotonic()
    while not await is_disconnected():
        await asyncio.sleep(poll_s)
        try:
            size = path.stat().st_size
        except OSError:
            size = 0
        if size < offset:  # truncated: a training resumed from an older checkpoint
            points, offset = _read_lines(path, 0)
            yield sse("history", {"points": points, "state": state})
        elif size > offset:
            points, offset = _read_lines(path, offset)
            for p in points:
                p["received"] = time.time()
                yield sse("point", p)
        now_state = workspace.state(name)
        if now_state != state:
            state = now_state
            yield sse("state", {"state": state})
        if time.monotonic() - last_beat > HEARTBEAT_S:
            last_beat = time.monotonic()
            yield ": keep-alive\n\n"


# ---- the live view ------------------------------------------------------------------------------

class Replay:
    """Car poses of one training iteration, by episode and step, from its simtrace file (training
    iteration N is logged in `<N-1>-iteration.csv`, as AWS numbers them)."""

    def __init__(self, path: Path, iteration: int):
        from racerlab.logs.read import read_simtrace_csv

        table = read_simtrace_csv(path.read_bytes(), str(path))
        cols = {k: table.column(k).to_numpy() for k in ("episode", "x", "y", "yaw")}
        self.path, self.iteration = path, iteration
        episodes, starts = np.unique(cols["episode"], return_index=True)
        order = np.argsort(starts)[:MAX_VIEW_CARS]
        bounds = list(starts[np.argsort(starts)]) + [len(cols["episode"])]
        self.cars = []
        for k in order:
            lo = starts[k]
            hi = min(b for b in bounds if b > lo)
            self.cars.append(np.stack([cols["x"][lo:hi], cols["y"][lo:hi], cols["yaw"][lo:hi]], axis=1))
        self.episodes = [int(e) for e in episodes[order]]

    def poses(self, step: int) -> list[np.ndarray]:
        return [c[step % len(c)] for c in self.cars]


def newest_replay(model_dir: Path, current: Replay | None) -> Replay | None:
    files = logs.simtrace_files(logs.training_simtrace_dir(model_dir))
    if not files:
        return None
    last = max(files)
    if current is not None and current.iteration == last + 1:
        return current
    try:
        return Replay(files[last], last + 1)
    except (OSError, ValueError, KeyError):  # a file being replaced: keep what we have
        return current


class Sensors:
    """What one car of a model sees at given poses: a `World` (one car; a pair in a head-to-model race) built as the
    model's training builds its worlds (`train.worlds.WorldBuilder`: the model's observation, look, stereo, lidar,
    race objects and car), so the live view shows the frames the model trains on. No reward runs and nothing is
    randomised."""

    def __init__(self, folder):
        from racerlab.sim.sensors.geometry import lidar_ray_angles
        from racerlab.train.worlds import EVAL_SEED, WorldBuilder

        cfg = folder.config()
        cars = 2 if cfg.race.head_to_model else 1  # a head-to-model world pairs its cars; car 0 is the one shown
        self.world = WorldBuilder(cfg, folder.metadata(), None).world(cfg.track.names[0], cars, EVAL_SEED,
                                                                      training=False)
        self.world.sim.reset()
        self.ahead = MODEL_POINT_AHEAD_M
        self.angles = [round(float(a), 4) for a in lidar_ray_angles()]

    def observe(self, x: float, y: float, yaw_deg: float) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The model's camera frame (120, 160, channels) uint8 and its lidar's 64 ranges (m) at a logged model-point
        pose; None for the sensor the model lacks."""
        yaw = math.radians(yaw_deg)
        self.world.sim.relocate(0, x - self.ahead * math.cos(yaw), y - self.ahead * math.sin(yaw), yaw)
        obs = self.world.observe()
        parts = getattr(self.world.observation, "parts", None) or {self.world.observation.name: self.world.observation}
        frames = obs if isinstance(obs, dict) else {self.world.observation.name: obs}
        camera = next((frames[k][0] for k in ("camera", "stereo") if k in frames), None)
        if "lidar" in frames:
            return camera, frames["lidar"][0]
        lidar = next((p.lidar for p in parts.values() if hasattr(p, "lidar")), None)  # a sector lidar: its ranges
        return camera, None if lidar is None else lidar.scan()[0]

    def at(self, x: float, y: float, yaw_deg: float) -> tuple[str | None, list[float] | None]:
        """The camera frame as a PNG data URI (a stereo pair side by side) and the lidar ranges (m), for a logged
        model-point pose; None for the sensor the model lacks."""
        import imageio.v3 as iio

        camera, ranges = self.observe(x, y, yaw_deg)
        uri = None
        if camera is not None:
            png = iio.imwrite("<bytes>", np.hstack([camera[:, :, c] for c in range(camera.shape[2])]), extension=".png")
            uri = "data:image/png;base64," + base64.b64encode(png).decode()
        return uri, None if ranges is None else [round(float(r), 3) for r in ranges]



def model_sees(folder) -> list[str]:
    """Which of the live view's panels show what the model sees: "camera" and/or "lidar"; [] for a features model
    (a vector, nothing to draw) or a folder whose model_metadata.json cannot be read."""
    from racerlab.errors import RacerlabError
    from racerlab.model.metadata import CAMERAS, LIDARS

    try:
        sensor = folder.metadata().sensor
    except RacerlabError:
        return []
    return [kind for kind, names in (("camera", CAMERAS), ("lidar", LIDARS)) if any(s in names for s in sensor)]


async def live_view(workspace, name: str, car: int, is_disconnected, hz: int = VIEW_HZ):
    folder = workspace.folder(name)
    sees = await asyncio.to_thread(model_sees, folder)
    replay, sensors = None, None
    t0 = time.monotonic()
    frame = 0
    while not await is_disconnected():
        replay = await asyncio.to_thread(newest_replay, folder.path, replay)
        if replay is None:
            yield sse("waiting", {"message": "no training iteration logged yet"})
            await asyncio.sleep(1.0)
            continue
        step = int((time.monotonic() - t0) * STEPS_PER_SECOND)
        poses = replay.poses(step)
        msg = {"iteration": replay.iteration, "step": step, "sees": sees,
               "cars": [[round(float(p[0]), 3), round(float(p[1]), 3), round(float(p[2]), 1)] for p in poses]}
        if frame % CAMERA_EVERY == 0 and poses:
            k = min(max(car, 0), len(poses) - 1)
            msg["car"] = k
            if sees:  # a features model sees a vector: no frame or scan to draw
                if sensors is None:
                    sensors = await asyncio.to_thread(Sensors, folder)
                camera, lidar = await asyncio.to_thread(sensors.at, *poses[k])
                if "camera" in sees:
                    msg["camera"] = camera
                if "lidar" in sees:
                    msg["lidar"], msg["angles"] = lidar, sensors.angles
        yield sse("view", msg)
        frame += 1
        await asyncio.sleep(1.0 / hz)

