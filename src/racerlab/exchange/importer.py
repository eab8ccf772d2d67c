"""Import a console / DRoA / DRfC / car model (folder or archive) as a racerlab model folder.

The weights come from the TF checkpoint when there is one (policy `network_1` and value `network_0`),
else from a frozen `model.pb` (policy only; the value network starts fresh). Nothing imported is
executed: archives are checked member by member before anything is extracted, TensorFlow only reads
tensors from the checkpoint bundle, the graph is parsed as a protobuf and never run, and
`reward_function.py` is kept as text (see `local.write_imported_model`).
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import tarfile
import tempfile
import zipfile
from pathlib import Path, PurePosixPath

from racerlab.errors import ConfigError, RacerlabError
from racerlab.exchange.coach import POLICY_NETWORK, VALUE_NETWORK, load_into_torch
from racerlab.exchange.local import (
    aws_shapes,
    load_model_metadata,
    parse_hyperparameters_text,
    write_imported_model,
)
from racerlab.logs import scratch_dir
from racerlab.spec import MAX_ARCHIVE_BYTES

CKPT_RE = re.compile(r"^(\d+)_Step-(\d+)\.ckpt\.index$")
KEPT = ("reward_function.py", "hyperparameters.json", "training_params.yaml", "model_metadata.json")


MAX_MEMBERS = 100_000  # a DeepRacer model archive holds a few dozen
MAX_TEXT_BYTES = 1 << 20  # reward_function.py, the JSON and YAML files, the checkpoint markers
MARKERS = (".coach_checkpoint", "deepracer_checkpoints.json")
WEIGHTS_RE = re.compile(r"^(model(_\d+)?\.pb|\d+_Step-\d+\.ckpt\.(index|meta|data-\d+-of-\d+))$")


def wanted(name: str) -> bool:
    """Whether the importer reads a file of this base name (everything else in an archive is never written)."""
    return name in KEPT or name in MARKERS or bool(WEIGHTS_RE.match(name))


def member_limit(name: str) -> int | None:
    """The most bytes a member of this base name may unpack to, None for a member the importer does not read (it is
    never written): a model's weights up to MAX_ARCHIVE_BYTES, its text files up to MAX_TEXT_BYTES."""
    if not wanted(name):
        return None
    return MAX_ARCHIVE_BYTES if WEIGHTS_RE.match(name) else MAX_TEXT_BYTES


def _check_member(archive: Path, name: str, is_file: bool, is_dir: bool, size: int = 0, sparse: bool = False,
                  keep=member_limit) -> None:
    p = PurePosixPath(name.replace("\\", "/"))
    if p.is_absolute() or name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name) or ".." in p.parts:
        raise ConfigError(f"{archive}: member {name!r} would be written outside the model folder (absolute path or "
                          "'..'); refusing to extract it. Re-create the archive with relative paths")
    if not (is_file or is_dir):
        raise ConfigError(f"{archive}: member {name!r} is a link or device, not a file; refusing to extract it. "
                          "Re-create the archive with plain files")
    if sparse:
        raise ConfigError(f"{archive}: member {name!r} is a sparse file (its {size} bytes would be written in "
                          "full); refusing to extract it. Re-create the archive without --sparse")
    limit = keep(p.name) if is_file else None
    if limit is not None and size > limit:
        raise ConfigError(f"{archive}: member {name!r} unpacks to {size} bytes, more than a DeepRacer model's "
                          f"{p.name} (<= {limit} bytes); refusing to extract it")


def safe_extract(archive: Path, dest: Path, keep=member_limit) -> None:
    """Extract the files the importer reads from a .tar(.gz) or .zip into `dest`, after checking every member
    (no absolute paths, no '..', no links, devices or sparse files, bounded member count, member sizes and
    total size); a bad member refuses the whole archive before any write. Other members are never written.
    `keep(base name)` says which members are extracted and their size limit (`member_limit`: the importer's)."""
    try:
        if zipfile.is_zipfile(archive):
            with zipfile.ZipFile(archive) as z:
                infos = z.infolist()
                _check_count(archive, len(infos))
                for i in infos:
                    _check_member(archive, i.filename, not i.is_dir(), i.is_dir(), i.file_size, keep=keep)
                kept = [i for i in infos if not i.is_dir() and keep(PurePosixPath(i.filename).name) is not None]
                _check_size(archive, sum(i.file_size for i in kept))
                z.extractall(dest, members=kept)
            return
        with tarfile.open(archive) as tar:
            members = []
            for m in tar:
                members.append(m)
                _check_count(archive, len(members))
                _check_member(archive, m.name, m.isfile(), m.isdir(), m.size, m.issparse(), keep=keep)
            kept = [m for m in members if m.isfile() and keep(PurePosixPath(m.name).name) is not None]
            _check_size(archive, sum(m.size for m in kept))
            if hasattr(tarfile, "data_filter"):
                tar.extractall(dest, members=kept, filter="data")
            else:  # pragma: no cover - Python < 3.11.4; the members were checked above
                tar.extractall(dest, members=kept)
    except (tarfile.TarError, zipfile.BadZipFile, EOFError, OSError) as exc:
        if isinstance(exc, OSError) and exc.errno is not None:
            raise RacerlabError(f"{dest}: cannot unpack {archive.name} ({exc.strerror}); free some disk space "
                                "or set TMPDIR to a folder with room") from None
        raise ConfigError(f"{archive}: not a readable .tar.gz or .zip ({type(exc).__name__}: {exc}); download "
                          "the model again") from None


def _check_count(archive: Path, n: int) -> None:
    if n > MAX_MEMBERS:
        raise ConfigError(f"{archive}: more than {MAX_MEMBERS} members, far more than a DeepRacer model holds; "
                          "not extracting it")


def _check_size(archive: Path, total: int) -> None:
    if total > MAX_ARCHIVE_BYTES:
        raise ConfigError(f"{archive}: unpacks to {total / 2**30:.1f} GiB, more than a DeepRacer model "
                          f"(<= {MAX_ARCHIVE_BYTES / 2**30:g} GiB); not extracting it")


def plain_files(root: Path) -> list[Path]:
    """The regular files under `root`, never following a symbolic link; a link in place of a file the importer
    reads is refused (it could point at any file of this machine)."""
    found = []
    for folder, dirs, names in os.walk(root):
        for n in dirs + names:
            p = Path(folder) / n
            if p.is_symlink() and (wanted(n) or n in dirs):
                raise ConfigError(f"{p}: a symbolic link; racerlab imports plain files and folders only. Copy what "
                                  "it points to into the model folder")
            if n in names and not p.is_symlink() and p.is_file():
                found.append(p)
    return found


class ModelFiles:
    """Where the pieces of an AWS model are in an unpacked tree."""

    def __init__(self, root: Path):
        self.root = root
        files = plain_files(root)
        self.metadata = _pick(files, "model_metadata.json")
        self.pb = _pick_pb(files)
        self.checkpoint = _pick_checkpoint(root, files)
        self.kept = {name: p for name in KEPT if (p := _pick(files, name)) is not None}

    def require(self, where: Path) -> None:
        if self.metadata is None:
            raise ConfigError(f"{where}: no model_metadata.json; a DeepRacer model holds one at its root or in model/")
        if self.pb is None and self.checkpoint is None:
            raise ConfigError(f"{where}: no TF checkpoint (<N>_Step-<S>.ckpt.index) and no model.pb; nothing to "
                              "take weights from")


def _pick(files: list[Path], name: str) -> Path | None:
    hits = sorted((p for p in files if p.name == name), key=lambda p: len(p.parts))
    return hits[0] if hits else None


def _pick_pb(files: list[Path]) -> Path | None:
    pbs = [p for p in files if p.suffix == ".pb"]
    car = [p for p in pbs if p.name == "model.pb"]
    if car:
        return car[0]
    numbered = sorted((p for p in pbs if re.match(r"^model_\d+\.pb$", p.name)), key=lambda p: int(p.stem[6:]))
    return numbered[-1] if numbered else None


def _pick_checkpoint(root: Path, files: list[Path]) -> Path | None:
    """The prefix of the checkpoint .coach_checkpoint / deepracer_checkpoints.json name, else the newest one."""
    indexes = {p.name[: -len(".index")]: p for p in files if CKPT_RE.match(p.name)}
    if not indexes:
        return None
    for marker in [p for p in files if p.name in (".coach_checkpoint", "deepracer_checkpoints.json")]:
        text = marker.read_text(errors="replace")
        names = [text.strip()] if marker.name == ".coach_checkpoint" else _index_names(text)
        for name in names:
            if name in indexes:
                return indexes[name].with_suffix("")
    newest = max(indexes, key=lambda n: int(n.split("_", 1)[0]))
    return indexes[newest].with_suffix("")


def _index_names(text: str) -> list[str]:
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError):
        return []
    return [str(data.get(k, {}).get("name", "")) for k in ("best_checkpoint", "last_checkpoint")
            if isinstance(data.get(k), dict)]


def read_training_params(text: str) -> dict[str, str]:
    """The flat `KEY: "value"` lines of a training_params.yaml (no YAML library, nothing evaluated)."""
    out = {}
    for line in text.splitlines():
        m = re.match(r"^([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*?)\s*$", line)
        if m:
            out[m.group(1)] = m.group(2).strip("'\"")
    return out


def import_model(path, dst=None) -> Path:
    """Make a racerlab model folder (default: `<name>-imported` here) from an AWS model folder or archive.

    The folder is built in a private temporary folder beside the destination and renamed into place at the
    end, only while the name is still free: a failed or interrupted import leaves nothing at the name, and two
    imports into one name never touch each other's files."""
    src = Path(path)
    if not src.exists():
        raise RacerlabError(f"{src}: no such file or folder")
    name = re.sub(r"(\.tar\.gz|\.tgz|\.tar|\.zip)$", "", src.name) or "model"
    out = Path(dst) if dst else Path(f"{name}-imported")
    check_destination(out)
    with scratch_dir("import") as tmp:
        root = src
        if src.is_file():
            root = tmp / "unpacked"
            safe_extract(src, root)
        files = ModelFiles(root)
        files.require(src)
        return _import_tree(src, files, out)


def check_destination(out: Path) -> None:
    """A new model folder's name must be free (or an empty folder)."""
    if out.exists() and not out.is_dir():
        raise RacerlabError(f"{out}: a file of that name exists; import into a new folder name")
    if out.is_dir() and any(out.iterdir()):
        raise RacerlabError(f"{out}: already exists and is not empty; import into a new folder")


def _claim(staged: Path, out: Path) -> None:
    """Rename the finished folder onto `out` while that name is free or an empty folder (one atomic rename)."""
    try:
        os.rename(staged, out)
    except OSError as exc:
        if out.exists() or exc.errno in (errno.EEXIST, errno.ENOTEMPTY, errno.ENOTDIR):
            raise RacerlabError(f"{out}: created meanwhile by another import or program; nothing was written "
                                "there. Import again into a new folder name") from None
        raise


def _import_tree(src: Path, files: ModelFiles, out: Path) -> Path:
    from racerlab.agent import build_ppo_networks

    meta = load_model_metadata(files.metadata)
    if meta.training_algorithm != "clipped_ppo":
        raise ConfigError(f"{files.metadata}: training_algorithm {meta.training_algorithm!r}: racerlab imports "
                          "clipped_ppo models (SAC's rl_coach variable names are not pinned down)")
    shapes = aws_shapes(meta)
    policy, value = build_ppo_networks(shapes, meta)
    if files.checkpoint is not None:
        from racerlab.exchange.tfckpt import CheckpointReader

        reader = CheckpointReader(files.checkpoint)
        where, lookup = f"{files.checkpoint}.index", reader.lookup
        load_into_torch(value, lookup, VALUE_NETWORK, meta, shapes, where)
        source = {"weights": files.checkpoint.name, "value_network": "imported"}
    else:
        from racerlab.exchange.graphdef import FrozenGraph

        where, lookup = str(files.pb), FrozenGraph(files.pb, files.pb.read_bytes()).lookup
        source = {"weights": files.pb.name, "value_network": "new (a frozen graph has only the policy)"}
    load_into_torch(policy, lookup, POLICY_NETWORK, meta, shapes, where)
    kept = {name: p.read_bytes() for name, p in files.kept.items()}
    hp = parse_hyperparameters_text(kept["hyperparameters.json"].decode(errors="replace"),
                                    str(files.kept["hyperparameters.json"])) if "hyperparameters.json" in kept else None
    params = read_training_params(kept.get("training_params.yaml", b"").decode(errors="replace"))
    track = _known_track(params.get("WORLD_NAME"))
    note = {"from": str(src.resolve()), **source, "hyperparameters": "imported" if hp else "racerlab defaults",
            "track": track or "racerlab default", "reward_function": "kept as imported/reward_function.py.txt"}
    parent = out.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.importing-", dir=parent))
    except OSError as exc:
        raise RacerlabError(f"{out}: cannot create the model folder there ({exc.strerror}); choose another "
                            "place") from None
    try:
        write_imported_model(stage / "model", meta, {"policy": policy, "value": value}, hp, kept, track, note)
        _claim(stage / "model", out)
    except OSError as exc:
        raise RacerlabError(f"{out}: cannot write the imported model ({exc.strerror}); free some disk space and "
                            "import again") from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)  # the staging folder, never the destination
    return out


def _known_track(name: str | None) -> str | None:
    if not name:
        return None
    from racerlab import track as tracks

    try:
        tracks.load(name)
    except RacerlabError:
        return None
    return name
