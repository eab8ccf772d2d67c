"""Export a racerlab model: the physical car's archive, DRoA's import archive and DRfC's folder layout.

- car: `<model>-car.tar.gz` = `model_metadata.json` + `agent/model.pb` (frozen graph, `graphdef`).
- DRoA: `<model>-droa.tar.gz` = the tree below, which DRoA's "Import model" takes.
- DRfC: the same tree in a folder, as `dr-upload-model` lays it out under `s3://bucket/prefix/`:

      model/<N>_Step-<S>.ckpt.{index,data-00000-of-00001,meta}   TF checkpoint, rl_coach names (`tfckpt`)
      model/model_<N>.pb, model/model_metadata.json, model/.coach_checkpoint, model/deepracer_checkpoints.json
      ip/hyperparameters.json, model_metadata.json, reward_function.py, training_params.yaml

Every export opens the model through `ModelFolder.open` (`local.open_for_export`: a checkpoint that cannot be
read, holds non-finite weights or does not match model_metadata.json is refused with `errors.ModelRefused`) and
converts the networks `local.car_policy` gives for the AWS sensors' inputs.
"""

from __future__ import annotations

import io
import json
import os
import tarfile
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from racerlab.errors import ConfigError, RacerlabError
from racerlab.exchange.coach import CAR_SENSORS, POLICY_NETWORK, POLICY_OUTPUT, PREFIX, SAC_OUTPUT, ppo_towers
from racerlab.exchange.coach import tower_from_torch as _tower
from racerlab.exchange.graphdef import build_graph, graph_bytes
from racerlab.exchange.local import OpenModel, open_for_export
from racerlab.logs.atomic import check_output

if TYPE_CHECKING:
    from racerlab.agent import InferencePolicy


def policy_tower(policy: InferencePolicy):
    """(tower, scope, output node, activation) of the policy the car runs (`local.car_policy` of an opened model):
    clipped PPO's `network_1` with its softmax (discrete) or mean (continuous), or SAC's actor with tanh of its
    mean."""
    meta = policy.metadata
    if meta.training_algorithm == "sac":
        actor = policy.networks["actor"]
        tower = _tower(actor, meta, policy.shapes, "sac_policy_head_0/policy_mean")
        d = tower.head.kernel.shape[1] // 2  # the actor's head gives (mean, log-std); the car takes tanh(mean)
        tower.head.kernel, tower.head.bias = tower.head.kernel[:, :d], tower.head.bias[:d]
        return tower, SAC_OUTPUT.rsplit("/", 2)[0], SAC_OUTPUT, "tanh"
    tower, _ = ppo_towers(policy.networks["policy"], policy.networks["value"], meta, policy.shapes)
    activation = "softmax" if meta.action_space_type == "discrete" else "identity"
    return tower, f"{PREFIX}/{POLICY_NETWORK}", POLICY_OUTPUT, activation


def frozen_graph(policy: InferencePolicy):
    """The car's frozen GraphDef of a model's policy (`local.car_policy`)."""
    return build_graph(*policy_tower(policy))


def car_inputs(policy: InferencePolicy) -> dict[str, tuple[int, ...]]:
    """The car's input placeholders (in the graph's order) -> one observation's shape."""
    tower, scope, _, _ = policy_tower(policy)
    base = scope.rsplit("/", 1)[0] + "/network_0"
    return {f"{base}/{e.sensor}/{e.sensor}": tuple(e.shape) for e in tower.embedders}


def car_feed(policy: InferencePolicy, obs: dict) -> dict:
    """racerlab observations ({"camera": (N, 120, 160, 1) uint8, "lidar": ...}) as the car feeds its inputs:
    {placeholder name: float32 array}, images raw 0-255."""
    tower, scope, _, _ = policy_tower(policy)
    base = scope.rsplit("/", 1)[0] + "/network_0"
    return {f"{base}/{e.sensor}/{e.sensor}": np.asarray(obs[e.key], np.float32) for e in tower.embedders}


def _check_car_sensors(meta) -> None:
    bad = [s for s in meta.sensor if s not in CAR_SENSORS]
    if bad:
        raise ConfigError(f"{meta.source}: the car has no {bad[0]} sensor (it takes {', '.join(CAR_SENSORS)}); "
                          "train a model with `racerlab init DIR --sensor camera` (or stereo, lidar)")


# The name in the gzip header of every archive `racerlab export` writes (the header's FNAME, which tar and the car's
# upload ignore): the mark of a file an export may replace without --force.
EXPORT_MARK = "racerlab-export"


def export_path(model_dir, out, kind: str, force: bool = False) -> Path:
    """Where an export of `model_dir` writes its `<model>-<kind>.tar.gz`, checked before anything is loaded or
    written: that name here when `out` is None, that name inside `out` when it is a folder (as `cp` puts a file into
    a folder), else `out` itself. Refused in one line: an empty name, a folder that is not there, a device or other
    special file, a file of the model folder, and an existing file an export did not write unless `force`."""
    default = f"{Path(model_dir).resolve().name}-{kind}.tar.gz"
    if out is not None and str(out) == "":
        raise ConfigError(f"-o '': no file name; give e.g. -o {default}, or leave -o out to write {default} here")
    folder = out is not None and str(out).endswith(("/", os.sep))
    out = Path(default if out is None else out)
    if out.is_dir():
        out = out / default
    elif folder:
        raise ConfigError(f"-o {out}{os.sep}: the folder {out} does not exist; create it or give a file name")
    path = check_output(out, "-o", f"a new file name such as {default}")
    if not path.exists() or _written_by_export(path):
        return path if out.is_symlink() else out  # the name as given, unless it is a link: then its target
    model = Path(model_dir).resolve()
    if path.is_relative_to(model):
        raise ConfigError(f"-o {out}: that is {path.relative_to(model)} of the model {model_dir}; an export never "
                          f"replaces a model's file: give a name outside it, e.g. -o {default}")
    if not force:
        raise ConfigError(f"-o {out}: the file exists and racerlab export did not write it; give another name, or add "
                          "--force to replace it")
    return path if out.is_symlink() else out


def _written_by_export(path: Path) -> bool:
    """Whether `path` is a gzip file whose header names EXPORT_MARK (RFC 1952: flags at byte 3, then the extra
    field when FEXTRA, then the zero-terminated name when FNAME)."""
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError:
        return False
    if len(head) < 10 or head[:3] != b"\x1f\x8b\x08" or not head[3] & 0x08:
        return False
    at = 10 + (2 + int.from_bytes(head[10:12], "little") if head[3] & 0x04 else 0)
    return head[at:head.find(b"\0", at)] == EXPORT_MARK.encode()


def _tar(entries: dict[str, bytes], out: Path) -> Path:
    """A .tar.gz of `entries` (archive name -> bytes), marked as an export's (`EXPORT_MARK`), written atomically."""
    from racerlab.logs import atomic_write_bytes

    buf = io.BytesIO()
    with tarfile.open(EXPORT_MARK, fileobj=buf, mode="w:gz", compresslevel=1) as tar:
        for name, data in entries.items():
            info = tarfile.TarInfo(name)
            info.size, info.mtime, info.mode = len(data), int(time.time()), 0o644
            tar.addfile(info, io.BytesIO(data))
    return atomic_write_bytes(out, buf.getvalue())


def export_car(model_dir, out=None, checkpoint: str | int = "best", force: bool = False) -> Path:
    """`<model>-car.tar.gz` for the physical car: model_metadata.json and agent/model.pb at the root."""
    out = export_path(model_dir, out, "car", force)
    model, policy = open_for_export(model_dir, checkpoint)
    _check_car_sensors(model.metadata)
    pb = graph_bytes(frozen_graph(policy))
    return _tar({"model_metadata.json": model.folder.metadata_path.read_bytes(), "agent/model.pb": pb}, out)


def export_onnx(model_dir, out=None, checkpoint: str | int = "best", force: bool = False) -> Path:
    """`<model>-onnx.tar.gz`: model_metadata.json and model.onnx at the root; the ONNX graph keeps the car
    graph's input and output names, with a free batch dimension (`onnxgraph`)."""
    out = export_path(model_dir, out, "onnx", force)
    from racerlab.exchange.onnxgraph import build_onnx, onnx_bytes

    model, policy = open_for_export(model_dir, checkpoint)
    _check_car_sensors(model.metadata)
    data = onnx_bytes(build_onnx(*policy_tower(policy)))
    return _tar({"model_metadata.json": model.folder.metadata_path.read_bytes(), "model.onnx": data}, out)


def export_tflite(model_dir, out=None, checkpoint: str | int = "best", force: bool = False) -> Path:
    """`<model>-tflite.tar.gz`: the community car's installed-model folder (`/opt/aws/deepracer/artifacts/<name>/`):
    model_metadata.json, model.pb, model.tflite (what its optimizer would make of model.pb, float32) and
    checksum.txt (md5 of model.pb, the car's mark of a finished install)."""
    out = export_path(model_dir, out, "tflite", force)
    import hashlib

    from racerlab.exchange.tflite import tflite_from_frozen_graph

    model, policy = open_for_export(model_dir, checkpoint)
    _check_car_sensors(model.metadata)
    _, _, output, _ = policy_tower(policy)
    pb = graph_bytes(frozen_graph(policy))
    lite = tflite_from_frozen_graph(pb, car_inputs(policy), output)
    return _tar({"model_metadata.json": model.folder.metadata_path.read_bytes(), "model.pb": pb,
                 "model.tflite": lite, "checksum.txt": f"{hashlib.md5(pb).hexdigest()}\n".encode()}, out)


def write_virtual_tree(model: OpenModel, policy: InferencePolicy, root: Path) -> list[Path]:
    """DRfC's / DRoA's tree of an opened clipped-PPO model (`policy`: its networks, `local.car_policy`) under `root`;
    returns the files written."""
    from racerlab.exchange.tfckpt import coach_variables, write_checkpoint

    meta = model.metadata
    if meta.training_algorithm == "sac":
        raise ConfigError(f"{model.folder.metadata_path}: SAC models cannot be exported to DRoA/DRfC yet "
                          "(rl_coach's SAC variable names are not pinned down); use --car, or train clipped_ppo")
    policy, value = ppo_towers(policy.networks["policy"], policy.networks["value"], meta, policy.shapes)
    info = model.checkpoint
    ckpt = f"{info.iteration}_Step-{info.steps}.ckpt"
    mdir = root / "model"
    mdir.mkdir(parents=True, exist_ok=True)
    written = write_checkpoint(mdir / ckpt, coach_variables(policy, value, info.steps))
    activation = "softmax" if meta.action_space_type == "discrete" else "identity"
    files = {
        f"model/model_{info.iteration}.pb": graph_bytes(build_graph(policy, f"{PREFIX}/{POLICY_NETWORK}",
                                                                    POLICY_OUTPUT, activation)),
        "model/.coach_checkpoint": f"{ckpt}\n".encode(),
        "model/deepracer_checkpoints.json": _checkpoint_index(
            ckpt, model.path.stat().st_mtime),
        "model/model_metadata.json": json.dumps(meta.to_json(), indent=2).encode(),
        "model_metadata.json": json.dumps(meta.to_json(), indent=2).encode(),
        "ip/hyperparameters.json": json.dumps(model.hyperparameters.to_json(), indent=2).encode(),
        "reward_function.py": model.folder.reward_path.read_bytes(),
        "training_params.yaml": training_params(model).encode(),
    }
    for name, data in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(data)
        written.append(root / name)
    return written


def _checkpoint_index(ckpt: str, saved_at: float) -> bytes:
    """deepracer_checkpoints.json with last and best both naming `ckpt`, as `dr-upload-model` writes it."""
    entry = {"name": ckpt, "time_stamp": round(saved_at, 3), "avg_eval_metric": 0.0}
    return json.dumps({"best_checkpoint": entry, "last_checkpoint": entry}, indent=2).encode()


def training_params(model: OpenModel) -> str:
    """training_params.yaml as DRfC writes it: flat keys, every value a quoted string."""
    try:
        track = model.config.track.names[0]
    except RacerlabError:
        track = "reInvent2019_track"
    name = model.name
    values = {
        "AWS_REGION": "us-east-1", "JOB_TYPE": "TRAINING", "RACE_TYPE": "TIME_TRIAL", "WORLD_NAME": track,
        "MODEL_METADATA_FILE_S3_KEY": "model_metadata.json", "REWARD_FILE_S3_KEY": "reward_function.py",
        "SAGEMAKER_SHARED_S3_PREFIX": name, "BODY_SHELL_TYPE": "deepracer", "CAR_NAME": name, "CAR_COLOR": "Black",
        "DISPLAY_NAME": name, "RACER_NAME": name, "ALTERNATE_DRIVING_DIRECTION": "False",
        "CHANGE_START_POSITION": "True", "ENABLE_DOMAIN_RANDOMIZATION": "False", "MIN_EVAL_TRIALS": "5",
        "NUMBER_OF_OBSTACLES": "0", "NUMBER_OF_BOT_CARS": "0",
    }
    return "".join(f'{k}: "{v}"\n' for k, v in values.items())


def export_droa(model_dir, out=None, checkpoint: str | int = "best", force: bool = False) -> Path:
    """`<model>-droa.tar.gz`: the tree DRoA's "Import model" takes, at the archive's root."""
    out = export_path(model_dir, out, "droa", force)
    model, policy = open_for_export(model_dir, checkpoint)
    with tempfile.TemporaryDirectory(prefix="racerlab-droa-") as tmp:
        files = write_virtual_tree(model, policy, Path(tmp))
        return _tar({p.relative_to(tmp).as_posix(): p.read_bytes() for p in sorted(files)}, out)


def export_drfc(model_dir, out_dir, checkpoint: str | int = "best") -> Path:
    """The tree DRfC's `dr-upload-model` puts under its S3 prefix (and DR_LOCAL_S3_PRETRAINED_PREFIX reads)."""
    out = Path(out_dir)
    if str(out_dir) == "" or out.exists() and (not out.is_dir() or any(out.iterdir())):
        what = "no folder name" if str(out_dir) == "" else "not a folder" if not out.is_dir() else \
            "already exists and is not empty"
        raise RacerlabError(f"--drfc {str(out_dir)!r}: {what}; export into a new folder")
    model, policy = open_for_export(model_dir, checkpoint)
    write_virtual_tree(model, policy, out)
    return out
