"""A stored submission raced under a race's rules: a pure function of (stored weights, rules, seed, racerlab).

`evaluate_stored(model_dir, rules, tracks_dir, out_dir)` opens the converted model (safetensors and JSON only:
`open_stored`), loads the race's pinned track and drives it with `racerlab.evaluate` (`evaluate_loaded`: the
race rules, continuous laps, penalties, resets, boxes or bot cars, the video), seeded with the race's seed, on the
race's car, one torch thread. The same inputs give the same laps bit for bit on every worker: nothing in it reads
the clock, the machine or a random source that is not seeded from the rules (`tests/league` checks two worker
processes against each other, and `racerlab league replay` checks a stored result). Worker processes also pin
the CPU kernels torch and oneDNN may choose (`PIN_ENV`), so that machines with wider vector units compute the
same floating-point sums.

What it writes in `out_dir`: the evaluation as `racerlab evaluate` writes it (evaluation-simtrace/0-iteration.csv,
EvalMetrics.json, summary.json, evaluation.mp4), with the model's and the rules' hashes added to summary.json and
EvalMetrics.json ("league"), and league.json: the outcome (status, score, per-lap table) the store records.
"""

from __future__ import annotations

import json
import os
import resource
import time
from pathlib import Path

from racerlab import __version__
from racerlab.league import scoring
from racerlab.league.convert import MODEL_JSON, WEIGHTS_NAME
from racerlab.league.rules import Rules, load_pinned
from racerlab.logs import atomic_write_json

# set before torch is imported in a worker (racerlab.league.worker): one kernel choice on every x86-64 machine
PIN_ENV = {"ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "OPENBLAS_CORETYPE": "Haswell"}
RESULT_NAME = "league.json"
# a leaderboard's video: the track 640 px wide (racerlab evaluate draws 960: 2.2x the pixels) and every second step
# (7.5 frames a second, still real time): the video was 70 % of a camera evaluation's CPU time at 15 fps
VIDEO_WIDTH_PX = 640
VIDEO_EVERY = 2


def pin_environment() -> None:
    """The evaluation's environment variables (`PIN_ENV`), where the caller has not chosen its own."""
    for key, value in PIN_ENV.items():
        os.environ.setdefault(key, value)


def open_stored(model_dir: Path):
    """A stored model as an `OpenModel` (what `evaluate_loaded` races): its weights alone (`WEIGHTS_ONLY_KEY`), read
    from safetensors. It went through the door (`ModelFolder.open`) when the submission was converted."""
    from safetensors.torch import load_file

    from racerlab.model import CheckpointInfo, ModelFolder, OpenModel, TrainingState
    from racerlab.model.checkpoint import WEIGHTS_ONLY_KEY

    folder = ModelFolder(model_dir)
    meta = folder.metadata()
    info = json.loads((model_dir / MODEL_JSON).read_text())
    agent: dict = {WEIGHTS_ONLY_KEY: True, "format": info["agent_format"]}
    for key, tensor in load_file(str(model_dir / WEIGHTS_NAME)).items():
        module, param = key.split(".", 1)
        agent.setdefault(module, {})[param] = tensor
    checkpoint = CheckpointInfo.parse(info["checkpoint"]) or CheckpointInfo(info["checkpoint"], 0, 0)
    state = TrainingState(agent=agent, metadata=meta.to_json(), observation=folder.config().run.observation)
    return OpenModel(folder, meta, checkpoint, state)


def evaluate_stored(model_dir: Path, rules: Rules, tracks_dir: Path, out_dir: Path, *, video: bool | None = None,
                    on_lap=None) -> dict:
    """Race the stored model in `model_dir` under `rules` and write its evaluation into `out_dir`; the outcome
    (also in out_dir/league.json). `video` overrides the rules' video (replays skip it)."""
    import torch

    from racerlab.evaluate.api import evaluate_loaded

    torch.set_num_threads(1)
    torch.manual_seed(rules.seed)
    t0, cpu0 = time.perf_counter(), _cpu_seconds()
    track = load_pinned(tracks_dir, *rules.driven_track)
    model = open_stored(model_dir)
    info = json.loads((model_dir / MODEL_JSON).read_text())
    res = evaluate_loaded(model, track, rules.race_rules(), ranking_laps=max(1, rules.min_laps),
                          video=rules.video if video is None else video, race=rules.race_config(), car=rules.car,
                          seed=rules.seed, out_dir=out_dir, on_lap=on_lap, video_width=VIDEO_WIDTH_PX,
                          video_title=f"model {info.get('model_hash', model_dir.name)[:12]} on {track.name}",
                          video_every=VIDEO_EVERY)
    sc = scoring.score(res.laps, rules)
    outcome = {**sc.to_json(), "laps": [lap.to_json() for lap in res.laps], "result": res.result.to_json(),
               "model_hash": info.get("model_hash", model_dir.name), "rules_hash": rules.hash, "seed": rules.seed,
               "racerlab_version": __version__, "steps": res.steps, "checkpoint": res.checkpoint,
               "eval_seconds": round(time.perf_counter() - t0, 3), "eval_cpu_seconds": round(_cpu_seconds() - cpu0, 3)}
    tag_evaluation(out_dir, {k: outcome[k] for k in ("model_hash", "rules_hash", "seed", "racerlab_version")})
    atomic_write_json(out_dir / RESULT_NAME, outcome, indent=2)
    return outcome


def tag_evaluation(out_dir: Path, tags: dict) -> None:
    """The model's and rules' hashes in summary.json and EvalMetrics.json (readers of the AWS schema ignore them)."""
    for name in ("summary.json", "EvalMetrics.json"):
        path = out_dir / name
        if path.is_file():
            doc = json.loads(path.read_text())
            doc["league"] = tags
            atomic_write_json(path, doc, indent=2 if name == "summary.json" else None)


def _cpu_seconds() -> float:
    """This process's CPU time and that of its finished children (the video's ffmpeg)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def same_laps(a: list[dict], b: list[dict]) -> list[str]:
    """Where two per-lap tables differ (empty: identical, every float bit for bit)."""
    if len(a) != len(b):
        return [f"{len(a)} laps against {len(b)}"]
    out = []
    for k, (x, y) in enumerate(zip(a, b, strict=True), 1):
        for key in sorted(set(x) | set(y)):
            if x.get(key) != y.get(key):
                out.append(f"lap {k} {key}: {x.get(key)!r} against {y.get(key)!r}")
    return out
