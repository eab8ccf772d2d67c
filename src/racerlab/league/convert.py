"""A submission becomes data: its checkpoint converted, in a locked-down child, into weights that cannot run code.

A submission is a racerlab model folder or an AWS model racerlab imports (console, DRoA and DRfC exports, the
car's archive), as a folder or a .tar.gz / .zip. `convert_upload` runs the whole reading of it in a child process
forked from a small server that has torch loaded already (so a conversion costs a fork, not an interpreter start):

1. the child first limits itself (`resource.setrlimit`: address space, CPU seconds, file size, no core dumps;
   a lower CPU priority than the web server's, `CHILD_NICE`) and the parent kills it at the deadline; at most
   `CONVERSIONS_AT_ONCE` children run at a time per server, the other uploads wait their turn;
2. it copies or unpacks only the files a model has, through `racerlab.exchange`'s archive checks (no links,
   devices, absolute paths or '..', bounded sizes and member count);
3. it opens the checkpoint through the model folder's one door (`ModelFolder.open`: `weights_only`, non-finite
   weights refused, the checkpoint's metadata against model_metadata.json), after importing an AWS model with
   `racerlab.exchange.import_model` (TensorFlow reads tensors only; a frozen graph is parsed, never run);
4. it writes the networks' weights as safetensors, with model_metadata.json, a small training.toml (the
   observation and camera look the network reads) and model.json.

No reward function runs and nothing from the submission is unpickled in this process: the parent reads back only
JSON, TOML and safetensors from the child's folder, and its exit status; the child's error is one line of text.
The model's content hash (`model_hash`) covers what decides how it drives: the metadata, the observation and
look, and every tensor's name, dtype, shape and bytes, so the same model packed twice has one hash.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
import re
import shutil
import signal
import threading
from dataclasses import dataclass
from pathlib import Path

from racerlab.errors import RacerlabError
from racerlab.league.store import LeagueError

MODEL_FORMAT = "racerlab.league.model/1"
WEIGHTS_NAME = "weights.safetensors"
MODEL_JSON = "model.json"
DEADLINE_S = 120.0  # a racerlab folder converts in well under a second, an AWS TF checkpoint in ~15 s
MEMORY_BYTES = 3 << 30  # beyond what the child had mapped when it started
CHECKPOINT_RE = re.compile(r"^\d+_Step-\d+\.pt$")
RACERLAB_TEXT = ("training.toml",)
NAME_RE = re.compile(r"[^A-Za-z0-9._ -]+")
ERROR_NAME = "error.txt"
MAX_WEIGHT = 1e6  # a trained network's weights are of order 1; past this its outputs saturate or overflow


@dataclass(frozen=True)
class Converted:
    """A converted submission in `folder` (not yet in the store)."""

    model_hash: str
    folder: Path
    source: str  # racerlab | aws-checkpoint | aws-pb
    checkpoint: str
    name: str
    sensor: tuple[str, ...]
    action_space_type: str


def keep(name: str) -> int | None:
    """The importer's members (`exchange.importer.member_limit`) and a racerlab folder's: checkpoints, training.toml."""
    from racerlab.exchange.importer import MAX_TEXT_BYTES, member_limit
    from racerlab.spec import MAX_ARCHIVE_BYTES

    if CHECKPOINT_RE.match(name):
        return MAX_ARCHIVE_BYTES
    if name in RACERLAB_TEXT:
        return MAX_TEXT_BYTES
    return member_limit(name)


def clean_name(name: str, fallback: str = "model") -> str:
    """A model's display name: printable letters, digits, '.', '_', '-' and spaces, at most 64."""
    text = NAME_RE.sub("", str(name or "")).strip()[:64]
    return text or fallback


CONVERSIONS_AT_ONCE = max(1, os.cpu_count() or 1)  # a flood of uploads queues here instead of forking a child each
CHILD_NICE = 5  # a conversion yields the CPU to the server's answers (leaderboards, status polls)
_converting = threading.BoundedSemaphore(CONVERSIONS_AT_ONCE)

# ---- the parent's side -----------------------------------------------------------------------------------------
_context = None


def _ctx():
    global _context
    if _context is None:
        if "forkserver" in mp.get_all_start_methods():
            _context = mp.get_context("forkserver")
            _context.set_forkserver_preload(["torch", "racerlab.model", "racerlab.league.convert"])
        else:  # pragma: no cover - platforms without fork
            _context = mp.get_context("spawn")
    return _context


def convert_upload(upload, work, checkpoint: str = "best", name: str = "", *, deadline_s: float = DEADLINE_S,
                   memory_bytes: int = MEMORY_BYTES) -> Converted:
    """Convert `upload` (a folder or an archive) in a child into `work`/model; a one-line LeagueError when refused."""
    upload, work = Path(upload), Path(work)
    if not upload.exists():
        raise LeagueError(f"{upload.name}: no such file or folder")
    if upload.is_symlink():
        raise LeagueError(f"{upload.name}: a symbolic link; submit the model folder or archive itself")
    work.mkdir(parents=True, exist_ok=True)
    with _converting:  # the deadline counts from the child's start, not from the wait for a turn
        proc = _ctx().Process(target=child_main, args=(str(upload), str(work), str(checkpoint), int(memory_bytes),
                                                       float(deadline_s)), daemon=True, name="racerlab-league-convert")
        proc.start()
        proc.join(deadline_s)
        killed = proc.is_alive()
        if killed:
            proc.kill()
            proc.join(10)
    if killed:
        raise LeagueError(f"{upload.name}: reading the model took longer than {deadline_s:g} s; it was stopped. "
                          "Submit a DeepRacer or racerlab model of the usual size")
    if proc.exitcode != 0:
        raise LeagueError(_child_error(work, proc.exitcode, upload, memory_bytes))
    return read_converted(work / "model", clean_name(name, clean_name(_stem(upload))))


def _stem(upload: Path) -> str:
    return re.sub(r"(\.tar\.gz|\.tgz|\.tar|\.zip)$", "", upload.name)


def _child_error(work: Path, code: int, upload: Path, memory_bytes: int) -> str:
    err = work / ERROR_NAME
    if err.is_file():
        text = err.read_text(errors="replace").strip().splitlines()
        if text:
            return text[0][:500]
    if code in (-signal.SIGKILL, -signal.SIGSEGV, -signal.SIGABRT) or code == 3:
        return (f"{upload.name}: reading the model needed more than {memory_bytes / 2**30:g} GiB of memory or "
                "crashed; it was stopped. Submit a DeepRacer or racerlab model of the usual size")
    if code == -signal.SIGXCPU:
        return f"{upload.name}: reading the model used too much CPU time; it was stopped"
    return f"{upload.name}: could not be read as a model (the converter ended with status {code})"


def read_converted(folder: Path, name: str) -> Converted:
    """The child's output, read as data only (JSON and safetensors), checked, and its content hash."""
    from racerlab.model import load_model_metadata

    info = json.loads((folder / MODEL_JSON).read_text())
    if info.get("format") != MODEL_FORMAT:
        raise LeagueError("the converter wrote an unknown model format", 500)
    meta = load_model_metadata(folder / "model_metadata.json")
    digest = model_hash(folder, meta.to_json(), info)
    info.update(model_hash=digest, name=name)
    (folder / MODEL_JSON).write_text(json.dumps(info, indent=2, sort_keys=True) + "\n")
    return Converted(digest, folder, info["source"], info["checkpoint"], name, tuple(meta.sensor),
                     meta.action_space_type)


def model_hash(folder: Path, metadata: dict, info: dict) -> str:
    """SHA-256 over the metadata, the observation and look, and every tensor (name, dtype, shape, bytes); a
    non-finite or absurd (> MAX_WEIGHT) weight is refused here too."""
    import numpy as np
    from safetensors import safe_open

    h = hashlib.sha256()
    head = {"format": MODEL_FORMAT, "metadata": metadata, "observation": info["observation"], "look": info["look"],
            "agent_format": info["agent_format"]}
    h.update(json.dumps(head, sort_keys=True, separators=(",", ":")).encode())
    with safe_open(str(folder / WEIGHTS_NAME), framework="np") as f:
        for key in sorted(f.keys()):
            arr = np.ascontiguousarray(f.get_tensor(key))
            if arr.dtype.kind == "f" and not np.isfinite(arr).all():
                raise LeagueError(f"the model's weights hold NaN or infinity ({key}); submit a checkpoint from "
                                  "before the training diverged")
            if arr.dtype.kind == "f" and arr.size and float(np.abs(arr).max()) > MAX_WEIGHT:
                raise LeagueError(f"the model's weights reach {float(np.abs(arr).max()):.3g} ({key}), beyond any "
                                  f"trained network's (<= {MAX_WEIGHT:g}); submit a checkpoint from before the "
                                  "training diverged")
            h.update(f"\0{key}\0{arr.dtype.str}\0{arr.shape}\0".encode())
            h.update(arr.tobytes())
    return h.hexdigest()


def store_converted(conv: Converted, models_dir: Path) -> Path:
    """Move a converted model into the store under its hash (kept as it is when that model is there already)."""
    dest = models_dir / conv.model_hash
    if dest.is_dir():
        return dest
    try:
        os.rename(conv.folder, dest)
    except OSError:
        if not dest.is_dir():
            raise
    return dest


# ---- the child's side ------------------------------------------------------------------------------------------
def limit_resources(memory_bytes: int, cpu_s: float) -> None:
    """The child's own limits, set before it reads a byte of the submission."""
    import resource

    vm = _mapped_bytes()
    resource.setrlimit(resource.RLIMIT_AS, (vm + memory_bytes, vm + memory_bytes))
    cpu = max(1, int(cpu_s))
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 5))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    os.nice(CHILD_NICE)
    from racerlab.spec import MAX_ARCHIVE_BYTES

    resource.setrlimit(resource.RLIMIT_FSIZE, (MAX_ARCHIVE_BYTES, MAX_ARCHIVE_BYTES))


def _mapped_bytes() -> int:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    except OSError:  # pragma: no cover - no /proc
        pass
    return 0


def child_main(upload: str, work: str, checkpoint: str, memory_bytes: int, deadline_s: float) -> None:
    """The child: limits, then stage, open, write; any refusal is one line in error.txt and exit status 2."""
    import sys

    out = Path(work)
    try:
        # racerlab's own modules load before the limits, which are for the submission: the forkserver's preload is
        # not there when another part of the process (the console's runs) started the one forkserver first
        import torch

        import racerlab.exchange.importer  # noqa: F401
        import racerlab.model  # noqa: F401

        torch.set_num_threads(1)
        limit_resources(memory_bytes, deadline_s)
        convert_in_child(Path(upload), out, checkpoint)
    except MemoryError:
        _fail(out, _memory_text(upload, memory_bytes), 3)
    except RacerlabError as exc:  # torch's allocator failing under the limit arrives wrapped in the loader's error
        _fail(out, _memory_text(upload, memory_bytes) if "allocate memory" in str(exc) else
              _scrub(str(exc), upload, out), 2)
    except Exception as exc:  # noqa: BLE001 - a hostile file must end in one line, not a traceback
        _fail(out, f"{Path(upload).name}: not a model racerlab can read ({type(exc).__name__}: "
                   f"{_scrub(str(exc), upload, out)})", 2)
    sys.stdout.flush()


def _memory_text(upload: str, memory_bytes: int) -> str:
    return (f"{Path(upload).name}: reading the model needed more than {memory_bytes / 2**30:g} GiB of memory; it was "
            "stopped. Submit a DeepRacer or racerlab model of the usual size")


def _scrub(text: str, upload: str, work: Path) -> str:
    """The message without the server's folders in it (the racer knows their file by its name)."""
    first = (text.strip().splitlines() or [""])[0]
    for folder, shown in ((str(work / "input"), Path(upload).name), (str(work / "imported"), Path(upload).name),
                          (str(work), ""), (str(Path(upload).parent) + os.sep, "")):
        first = first.replace(folder, shown)
    return first[:480]


def _fail(out: Path, message: str, code: int) -> None:
    (out / ERROR_NAME).write_text(message + "\n")
    os._exit(code)


def convert_in_child(upload: Path, out: Path, checkpoint: str) -> None:
    from racerlab.model import ModelFolder

    staged = out / "input"
    if upload.is_dir():
        stage_folder(upload, staged)
    else:
        from racerlab.exchange.importer import safe_extract

        safe_extract(upload, staged, keep=keep)
    root = model_root(staged, upload)
    if any(CHECKPOINT_RE.match(p.name) for p in (root / "checkpoints").glob("*.pt")):
        if not (root / "reward_function.py").is_file():  # the door asks for one; it is never run
            (root / "reward_function.py").write_text("# not part of the submission; a league never runs it\n")
        opened, source = ModelFolder(root).open(checkpoint), "racerlab"
    else:
        opened, source = _import_aws(staged, out, upload, checkpoint)
    write_stored(opened, out / "model", source)


def _import_aws(staged: Path, out: Path, upload: Path, checkpoint: str):
    from racerlab.exchange.importer import ModelFiles, import_model
    from racerlab.model import ModelFolder

    if checkpoint not in ("best", ""):
        raise LeagueError(f"{upload.name}: an AWS model races the checkpoint its export holds; submit it without "
                          f"choosing a checkpoint (asked for {checkpoint!r})")
    files = ModelFiles(staged)
    files.require(Path(upload.name))
    source = "aws-checkpoint" if files.checkpoint is not None else "aws-pb"
    imported = import_model(staged, out / "imported")
    return ModelFolder(imported).open("last"), source


def model_root(staged: Path, upload: Path) -> Path:
    """The folder that holds the model's model_metadata.json (the shallowest one)."""
    hits = sorted(staged.rglob("model_metadata.json"), key=lambda p: len(p.parts))
    if not hits:
        raise LeagueError(f"{upload.name}: no model_metadata.json; submit a racerlab model folder or a DeepRacer model "
                          "(console, DRoA or DRfC export, or the car's archive)")
    return hits[0].parent


def stage_folder(src: Path, dest: Path) -> None:
    """Copy the files a model has from a folder, with the archive checks: no links, no special files, sizes bounded."""
    from racerlab.exchange.importer import MAX_MEMBERS
    from racerlab.spec import MAX_ARCHIVE_BYTES

    total = count = 0
    for folder, dirs, names in os.walk(src):
        for n in dirs + names:
            p = Path(folder) / n
            count += 1
            if count > MAX_MEMBERS:
                raise LeagueError(f"{src.name}: more than {MAX_MEMBERS} files, far more than a model holds")
            if p.is_symlink():
                raise LeagueError(f"{p.relative_to(src)}: a symbolic link; submit plain files and folders only")
        for n in names:
            p = Path(folder) / n
            limit = keep(n)
            if limit is None or not p.is_file():
                continue
            size = p.stat().st_size
            total += size
            if size > limit or total > MAX_ARCHIVE_BYTES:
                raise LeagueError(f"{p.relative_to(src)}: {size} bytes, more than a model's {n} (<= {limit} bytes)")
            target = dest / p.relative_to(src)
            target.parent.mkdir(parents=True, exist_ok=True)
            _copy_nofollow(p, target)


def _copy_nofollow(src: Path, dst: Path) -> None:
    fd = os.open(src, os.O_RDONLY | os.O_NOFOLLOW)
    with os.fdopen(fd, "rb") as fin, open(dst, "wb") as fout:
        shutil.copyfileobj(fin, fout, 1 << 20)


DRIVING_NETWORKS = ("policy", "actor")  # PPO's policy network, SAC's actor: what chooses the actions


def network_weights(agent_state: dict) -> dict:
    """{"policy.<param>": tensor, ...}: the weights of the network that drives (`DRIVING_NETWORKS`). The value or
    critic networks, optimizers, counters and random state are left out: greedy actions never read them, and two
    uploads of one policy (a racerlab folder and its car export, whose value network is new) are one model."""
    import torch

    out = {}
    for module in DRIVING_NETWORKS:
        value = agent_state.get(module)
        if isinstance(value, dict) and value and all(isinstance(t, torch.Tensor) for t in value.values()):
            out.update({f"{module}.{k}": t.detach().cpu().contiguous() for k, t in value.items()})
    return out


def write_stored(opened, dest: Path, source: str) -> None:
    """The stored form of an opened model (`model.OpenModel`): weights.safetensors, model_metadata.json,
    training.toml, model.json."""
    from safetensors.torch import save_file

    dest.mkdir(parents=True)
    tensors = network_weights(opened.state.agent)
    if not tensors:
        raise LeagueError("the checkpoint holds no network weights")
    agent_format = str(opened.state.agent.get("format", ""))
    save_file(tensors, str(dest / WEIGHTS_NAME), metadata={"agent_format": agent_format})
    (dest / "model_metadata.json").write_text(json.dumps(opened.metadata.to_json(), indent=2) + "\n")
    trained = opened.config.race.type
    (dest / "training.toml").write_text(f'[run]\nobservation = "{opened.observation}"\nlook = "{opened.look}"\n'
                                        f'[race]\ntype = "{trained}"\n')
    info = {"format": MODEL_FORMAT, "source": source, "checkpoint": opened.checkpoint.name,
            "agent_format": agent_format, "observation": opened.observation, "look": opened.look,
            "trained_race_type": trained}
    (dest / MODEL_JSON).write_text(json.dumps(info, indent=2, sort_keys=True) + "\n")
