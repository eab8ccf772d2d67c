"""Sensor throughput on one core: camera frames/s, lidar car-steps/s, and Gymnasium's CarRacing-v3 for scale.

Prints one JSON line per measurement:
- `camera_render`: the camera observation alone (render + copy of the batch) at 1 and 64 cars, default look
  and with domain randomization; budget >= 10 000 frames/s at 64 cars;
- `camera_env`: the vector env stepping with the camera observation (dynamics, rules, render) at 64 cars;
- `stereo_render`: both eyes, 64 cars;
- `lidar_env`: the vector env with the lidar observation at 256 cars, as AWS (no walls, no objects), with the
  borders as walls, and with 6 box obstacles; budget >= 100 000 car-steps/s;
- `objects_vs_time_trial`: side by side in this process, the vector env with 6 boxes per car (an object
  avoidance race, `number_of_obstacles = 6`: boxes placed as AWS does, crash rule, objects_* params, the
  sensors see the boxes) against the time trial: camera at 64 cars and lidar at 256 cars, with the ratios
  (target >= 0.70 each). The trials alternate between the two, so that a load change hits both alike;
- `bots_vs_time_trial` (`--only bots`): side by side in the same way, the vector env at 64 cars with the
  `features` observation in a head-to-bot race (3 bot cars per car changing lanes, at 0.5 and at 1.0 m/s)
  against the time trial, without a reward function (no params built) and with one (the params dict of every
  car every step, `objects_*` included in the race; both call the same centre-line reward); target >= 0.70;
- `carracing_v3`: Gymnasium's CarRacing-v3 (96×96 RGB, Box2D, random actions) steps/s, and our 64-car camera
  rate divided by it (goal >= 50×). Needs `pip install "racerlab[bench]"`; skipped with a note otherwise.

Each rate is the best of several short trials (the machine may be shared; the best trial is the closest to an
idle core), with the median alongside. The process is pinned to one core; `load_avg` is the 1-minute load
average at the end, for judging how busy the machine was.

`--only camera` stops after the camera and stereo renders. `--cpu-time` measures rates per second of this
process's CPU time rather than wall time (steadier when other processes share the core).

`--compare REV` measures the camera renders of another commit against this checkout in one run: REV's `src/` is
exported (`git archive`) into a temporary folder kept per commit (so its compiled kernels are reused), and two
worker processes, one importing each checkout, render in turn on the same core, base / branch / branch / base in
every round, one short window each. It prints one `camera_compare` line per case (camera at 64 and at 1 car,
camera with domain randomization, stereo) with the medians of both and their ratio (branch / base), and the
median of the rounds' own ratios.

Usage: python benchmarks/sensor_throughput.py [--track NAME_OR_PATH] [--seconds 3] [--only camera|objects|bots]
       python benchmarks/sensor_throughput.py --compare e958da9 [--rounds 12] [--cpu-time]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

import numpy as np  # noqa: E402

from racerlab.sim.core import Simulator  # noqa: E402
from racerlab.sim.env import DeepRacerVectorEnv  # noqa: E402
from racerlab.sim.sensors import build_observation  # noqa: E402
from racerlab.spec import RaceConfig  # noqa: E402

TRIALS = 10
CLOCK = [time.perf_counter]  # --cpu-time: time.process_time, this process's own CPU time


def rates(fn, units_per_call: float, seconds: float) -> tuple[float, float]:
    """(best, median) units per second over TRIALS trials of about seconds / TRIALS each."""
    fn()  # warm up (compilation is cached, but touch every path)
    out = []
    for _ in range(TRIALS):
        calls = 0
        t0 = CLOCK[0]()
        while True:
            fn()
            calls += 1
            elapsed = CLOCK[0]() - t0
            if elapsed >= seconds / TRIALS:
                break
        out.append(units_per_call * calls / elapsed)
    return max(out), statistics.median(out)


def emit(line: dict) -> None:
    line["load_avg"] = round(os.getloadavg()[0], 2)
    print(json.dumps(line), flush=True)


def camera_render(track, cars: int, name: str, seconds: float) -> tuple[float, float]:
    sim = Simulator(track, cars, seed=0)
    base, _, opts = name.partition(":")
    obs = build_observation(base, sim, options=tuple(o for o in opts.split(",") if o))
    return rates(obs, cars, seconds)


def camera_renders(track, sec: float) -> float:
    """The camera at 1 and 64 cars, with and without domain randomization, and stereo; returns the 64-car rate."""
    cam64 = 0.0
    for name in ("camera", "camera:dr"):
        for cars in (1, 64):
            best, med = camera_render(track, cars, name, sec)
            line = {"bench": "camera_render", "observation": name, "cars": cars, "frames_per_s": round(best),
                    "median": round(med)}
            if cars == 64 and name == "camera":
                cam64 = best
                line["budget"] = ">= 10000"
            emit(line)
    best, med = camera_render(track, 64, "stereo", sec)
    emit({"bench": "stereo_render", "cars": 64, "frames_per_s": round(best), "median": round(med)})
    return cam64


def env_stepper(track, cars: int, observation: str, boxes: int = 0, race=None, reward=None):
    """A function that steps a vector env of `cars` cars once with random actions."""
    env = DeepRacerVectorEnv(cars, track, observation=observation, race=race, reward_function=reward)
    env.reset(seed=0)
    if boxes:
        _place_boxes(env, boxes)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, env.single_action_space.n, size=(64, cars))
    k = [0]

    def step():
        env.step(actions[k[0] % 64])
        k[0] += 1

    return step


def env_rate(track, cars: int, observation: str, seconds: float, boxes: int = 0) -> tuple[float, float]:
    return rates(env_stepper(track, cars, observation, boxes), cars, seconds)


def side_by_side(fns: dict, units_per_call: float, seconds: float) -> dict[str, tuple[float, float]]:
    """(best, median) rate of each function, their trials interleaved."""
    for fn in fns.values():
        fn()
    out: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(TRIALS):
        for key, fn in fns.items():
            calls = 0
            t0 = time.perf_counter()
            while (elapsed := time.perf_counter() - t0) < seconds / TRIALS or calls == 0:
                fn()
                calls += 1
            out[key].append(units_per_call * calls / elapsed)
    return {k: (max(v), statistics.median(v)) for k, v in out.items()}


def objects_vs_time_trial(track, seconds: float) -> None:
    race = RaceConfig(type="object_avoidance", number_of_obstacles=6)
    for observation, cars in (("camera", 64), ("lidar", 256)):
        r = side_by_side({"time_trial": env_stepper(track, cars, observation),
                          "6_boxes": env_stepper(track, cars, observation, race=race)}, cars, seconds)
        emit({"bench": "objects_vs_time_trial", "observation": observation, "cars": cars,
              "time_trial_car_steps_per_s": round(r["time_trial"][0]), "boxes_car_steps_per_s": round(r["6_boxes"][0]),
              "ratio": round(r["6_boxes"][0] / r["time_trial"][0], 3),
              "ratio_of_medians": round(r["6_boxes"][1] / r["time_trial"][1], 3), "target": ">= 0.70"})


def centre_line_reward(params) -> float:
    """A reward that reads the params every race has (the AWS console's 'follow the centre line', shortened)."""
    return 1.0 if params["distance_from_center"] <= 0.25 * params["track_width"] else 1e-3


def bots_vs_time_trial(track, seconds: float) -> None:
    cars = 64
    for reward in (None, centre_line_reward):
        fns = {"time_trial": env_stepper(track, cars, "features", reward=reward)}
        for speed in (0.5, 1.0):
            race = RaceConfig(type="head_to_bot", number_of_bot_cars=3, bot_car_speed=speed, is_lane_change=True)
            fns[f"bots_{speed}"] = env_stepper(track, cars, "features", race=race, reward=reward)
        r = side_by_side(fns, cars, seconds)
        tt = r.pop("time_trial")
        for key, (best, med) in r.items():
            emit({"bench": "bots_vs_time_trial", "observation": "features", "cars": cars, "bot_cars": 3,
                  "bot_car_speed": float(key.split("_")[1]), "is_lane_change": True,
                  "reward_params": reward is not None,
                  "time_trial_car_steps_per_s": round(tt[0]), "bots_car_steps_per_s": round(best),
                  "ratio": round(best / tt[0], 3), "ratio_of_medians": round(med / tt[1], 3), "target": ">= 0.70"})


def _place_boxes(env, n: int) -> None:
    """n AWS-sized box obstacles (about 0.4 × 0.2 m) on the centre line, evenly spread; every car sees them."""
    t = env.sim.track
    s = np.arange(n) / n * t.length
    pts = t.point_at(s)
    yaw = t.heading_at(s)
    boxes = np.column_stack([pts, yaw, np.full(n, 0.2), np.full(n, 0.4)])
    env.world.observation.lidar.set_objects(boxes)


def carracing(seconds: float) -> tuple[float, float] | None:
    try:
        import gymnasium as gym

        env = gym.make("CarRacing-v3")
    except Exception as exc:  # noqa: BLE001 - box2d or pygame missing: say so and go on
        emit({"bench": "carracing_v3", "skipped": f"{type(exc).__name__}: {exc}",
              "install": 'pip install "racerlab[bench]"'})
        return None
    env.reset(seed=0)
    env.action_space.seed(0)

    def step():
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if term or trunc:
            env.reset()

    return rates(step, 1, seconds)


COMPARE_CASES = (("camera", 64), ("camera", 1), ("camera:dr", 64), ("stereo", 64))


def export_commit(rev: str) -> Path:
    """REV's src/ in a temporary folder named after its commit (reused: its numba cache survives between runs)."""
    repo = Path(__file__).resolve().parents[1]
    sha = subprocess.run(["git", "rev-parse", "--verify", f"{rev}^{{commit}}"], cwd=repo, capture_output=True,
                         text=True)
    if sha.returncode:
        raise SystemExit(f"--compare {rev}: not a commit of {repo} ({sha.stderr.strip()}); give a commit or branch")
    root = Path(tempfile.gettempdir()) / f"racerlab-compare-{sha.stdout.strip()[:12]}"
    if not (root / "src").is_dir():
        part = Path(tempfile.mkdtemp(prefix=root.name + ".", dir=root.parent))
        archive = subprocess.run(["git", "archive", sha.stdout.strip(), "src"], cwd=repo, capture_output=True,
                                 check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(part)], input=archive, check=True)
        try:
            part.rename(root)  # atomic: a half-written export is never taken for a whole one
        except OSError:  # another run exported it meanwhile
            shutil.rmtree(part, ignore_errors=True)
    return root / "src"


def worker(track, seconds: float) -> None:
    """Answer one JSON request a line on stdin ({"obs", "cars"}) with the rate of one window of that render."""
    made = {}
    for line in sys.stdin:
        req = json.loads(line)
        key = (req["obs"], req["cars"])
        if key not in made:
            sim = Simulator(track, req["cars"], seed=0)
            base, _, opts = req["obs"].partition(":")
            made[key] = build_observation(base, sim, options=tuple(o for o in opts.split(",") if o))
            made[key]()  # compile or load the kernels outside the window
        fn, calls = made[key], 0
        t0 = CLOCK[0]()
        while (elapsed := CLOCK[0]() - t0) < seconds or calls == 0:
            fn()
            calls += 1
        print(json.dumps(req["cars"] * calls / elapsed), flush=True)


def compare(rev: str, track: str, rounds: int, window: float, cpu_time: bool) -> None:
    """Base (REV) against this checkout, alternating windows in two worker processes (see the module docstring)."""
    import racerlab

    here = Path(racerlab.__file__).resolve().parents[1]
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--track", track, "--seconds", str(window)]
    procs = {}
    for name, src in (("base", export_commit(rev)), ("branch", here)):
        env = dict(os.environ, PYTHONPATH=str(src))
        procs[name] = subprocess.Popen(cmd + (["--cpu-time"] if cpu_time else []), stdin=subprocess.PIPE,
                                       stdout=subprocess.PIPE, text=True, env=env)

    def ask(name, obs, cars):
        p = procs[name]
        p.stdin.write(json.dumps({"obs": obs, "cars": cars}) + "\n")
        p.stdin.flush()
        answer = p.stdout.readline()
        if not answer:
            raise SystemExit(f"--compare: the {name} worker stopped (its error is above); is {rev} a racerlab "
                             f"checkout with {obs!r}?")
        return json.loads(answer)

    load0 = os.getloadavg()[0]
    for obs, cars in COMPARE_CASES:
        rates_ = {"base": [], "branch": []}
        for name in ("base", "branch"):
            ask(name, obs, cars)  # warm-up window
        for k in range(rounds):
            for name in ("base", "branch") if k % 2 == 0 else ("branch", "base"):
                rates_[name].append(ask(name, obs, cars))
        b, n = statistics.median(rates_["base"]), statistics.median(rates_["branch"])
        per_round = statistics.median(x / y for x, y in zip(rates_["branch"], rates_["base"], strict=True))
        emit({"bench": "camera_compare", "observation": obs, "cars": cars, "base": rev, "rounds": rounds,
              "clock": "cpu" if cpu_time else "wall", "base_frames_per_s": round(b), "branch_frames_per_s": round(n),
              "ratio": round(n / b, 3), "ratio_per_round": round(per_round, 3), "load_avg_start": round(load0, 2)})
    for p in procs.values():
        p.stdin.close()
        p.wait()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--track", default="lab_technical")
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--only", choices=["camera", "objects", "bots"],
                    help="only the camera and stereo renders, or the objects-vs-time-trial (6 boxes) or "
                         "bots-vs-time-trial (head-to-bot) comparison")
    ap.add_argument("--cpu-time", action="store_true",
                    help="rates per second of this process's CPU time instead of wall time: steadier on a shared "
                         "machine, where other processes take the core for part of the time")
    ap.add_argument("--compare", metavar="REV",
                    help="camera renders of commit REV against this checkout, alternating in one run")
    ap.add_argument("--rounds", type=int, default=12, help="--compare: windows per checkout and case")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.cpu_time:
        CLOCK[0] = time.process_time
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    sec = args.seconds
    if args.worker:
        worker(args.track, sec)
        return
    if args.compare:
        compare(args.compare, args.track, args.rounds, sec / TRIALS, args.cpu_time)
        return
    if args.only == "objects":
        objects_vs_time_trial(args.track, 2 * sec)
        return
    if args.only == "bots":
        bots_vs_time_trial(args.track, 2 * sec)
        return
    cam64 = camera_renders(args.track, sec)
    if args.only == "camera":
        return
    best, med = env_rate(args.track, 64, "camera", sec)
    emit({"bench": "camera_env", "cars": 64, "car_steps_per_s": round(best), "median": round(med)})
    for label, obs, boxes in (("aws", "lidar", 0), ("walls", "lidar:walls", 0), ("6_boxes", "lidar", 6)):
        best, med = env_rate(args.track, 256, obs, sec, boxes)
        emit({"bench": "lidar_env", "variant": label, "cars": 256, "car_steps_per_s": round(best),
              "median": round(med), "budget": ">= 100000"})
    objects_vs_time_trial(args.track, 2 * sec)
    cr = carracing(sec)
    if cr is not None:
        emit({"bench": "carracing_v3", "steps_per_s": round(cr[0]), "median": round(cr[1]),
              "camera_64_over_carracing": round(cam64 / cr[0], 1), "goal": ">= 50"})


if __name__ == "__main__":
    main()
