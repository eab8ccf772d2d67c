"""The model folder: the racer's three AWS files, racerlab's training.toml, checkpoints and lineage.

Checkpoints follow AWS's scheme (facts §9): `checkpoints/<N>_Step-<S>.pt` for iteration N after S
training env steps, N = 0 before any training; `deepracer_checkpoints.json` names the last and
the best; the last 4 plus the best are kept. Every file is written atomically (temporary name,
then rename), so a kill at any moment leaves the previous complete state. A trained model is read through
`ModelFolder.open` (`model.opened`: the checks every reader gets).
"""

from __future__ import annotations

import json
import pickle
import shlex
import time
from pathlib import Path

from racerlab.errors import ModelRefused, RacerlabError
from racerlab.logs import atomic_write_bytes, atomic_write_json, atomic_write_text, finite_json
from racerlab.model.checkpoint import CheckpointInfo, TrainingState
from racerlab.model.config import TrainingConfig, load_training_config
from racerlab.model.hyperparameters import Hyperparameters, load_hyperparameters
from racerlab.model.lock import TrainingLock
from racerlab.model.metadata import ModelMetadata, load_model_metadata
from racerlab.model.opened import OpenModel, open_model
from racerlab.reward import load_reward_function

KEEP_LAST = 4


class ModelFolder:
    """Paths and file I/O of one model folder."""

    def __init__(self, path):
        self.path = Path(path)

    # ---- paths -------------------------------------------------------------------------------
    @property
    def reward_path(self) -> Path:
        return self.path / "reward_function.py"

    @property
    def metadata_path(self) -> Path:
        return self.path / "model_metadata.json"

    @property
    def hyperparameters_path(self) -> Path:
        return self.path / "hyperparameters.json"

    @property
    def config_path(self) -> Path:
        return self.path / "training.toml"

    @property
    def checkpoints_dir(self) -> Path:
        return self.path / "checkpoints"

    @property
    def dagger_dir(self) -> Path:
        """A taught model's DAgger data set and fit, kept beside its checkpoints (racerlab.train.dagger_store)."""
        return self.checkpoints_dir / "dagger"

    @property
    def checkpoints_json(self) -> Path:
        return self.checkpoints_dir / "deepracer_checkpoints.json"

    @property
    def lock_path(self) -> Path:
        return self.path / "training.lock"

    @property
    def lineage_path(self) -> Path:
        return self.path / "lineage.json"

    @property
    def model_files(self) -> tuple[Path, ...]:
        """The four files that define the model: reward, metadata, hyperparameters, training.toml."""
        return self.reward_path, self.metadata_path, self.hyperparameters_path, self.config_path

    def checkpoint_path(self, info: CheckpointInfo) -> Path:
        return self.checkpoints_dir / info.name

    # ---- loading -----------------------------------------------------------------------------
    def require(self) -> None:
        if not self.path.is_dir():
            raise RacerlabError(f"{self.path}: no such model folder; create one with "
                                f"`racerlab init {shlex.quote(str(self.path))}`")
        for p in (self.reward_path, self.metadata_path):
            if not p.is_file():
                raise RacerlabError(f"{p}: missing; a model folder needs reward_function.py and "
                                    "model_metadata.json (hyperparameters.json and training.toml are optional)")

    def reward_function(self):
        return load_reward_function(self.reward_path)

    def metadata(self) -> ModelMetadata:
        return load_model_metadata(self.metadata_path)

    def hyperparameters(self) -> Hyperparameters:
        if not self.hyperparameters_path.is_file():
            return Hyperparameters(source=str(self.hyperparameters_path))
        return load_hyperparameters(self.hyperparameters_path)

    def config(self) -> TrainingConfig:
        return load_training_config(self.config_path)

    def tracks(self, default: bool = True) -> tuple[str, ...]:
        """Names (or paths) of the tracks the model trains on, from training.toml. Without that file the model
        trains on the default track, which `default=False` leaves out: then the folder names no track."""
        if not default and not self.config_path.is_file():
            return ()
        return self.config().track.names

    # ---- writing the model's files (each atomically: a kill leaves the old file or the new one) ----------
    def write_reward(self, text: str) -> None:
        self._write(self.reward_path, text)

    def write_metadata(self, metadata: ModelMetadata) -> None:
        self._write(self.metadata_path, json.dumps(metadata.to_json(), indent=2) + "\n")

    def write_hyperparameters(self, hp: Hyperparameters | dict) -> None:
        """hyperparameters.json from `Hyperparameters` or a dict of its keys (validated by the next read)."""
        self._write(self.hyperparameters_path, json.dumps(hp if isinstance(hp, dict) else hp.to_json(), indent=2)
                    + "\n")

    def write_config(self, cfg: TrainingConfig, header: str = "") -> None:
        """training.toml from `cfg`, after `header` (comment lines for the reader)."""
        self._write(self.config_path, header + cfg.to_toml())

    def write_lineage(self, lineage: dict) -> None:
        self._write(self.lineage_path, json.dumps(lineage, indent=2) + "\n")

    def copy_model_files(self, src: ModelFolder) -> None:
        """The four model files of `src` (those it has) into this folder."""
        for p in src.model_files:
            if p.is_file():
                self._write(self.path / p.name, p.read_bytes())

    def write_file(self, relative: str | Path, data: str | bytes) -> Path:
        """Any other file of the folder (such as an import's originals kept under `imported/`), atomically;
        `relative` must stay inside the folder."""
        path = self.path / relative
        if Path(relative).is_absolute() or ".." in Path(relative).parts:
            raise ValueError(f"{relative}: not a path inside {self.path}")
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, data.encode("utf-8") if isinstance(data, str) else data)
        return path

    def _write(self, path: Path, data: str | bytes) -> None:
        self.write_file(path.relative_to(self.path), data)

    # ---- the training lock ---------------------------------------------------------------------
    def lock(self) -> TrainingLock:
        """The folder's training lock (`with folder.lock(): ...`): one trainer per folder at a time."""
        return TrainingLock(self.lock_path)

    # ---- checkpoints -------------------------------------------------------------------------
    def checkpoints(self) -> list[CheckpointInfo]:
        if not self.checkpoints_dir.is_dir():
            return []
        found = [CheckpointInfo.parse(p.name) for p in self.checkpoints_dir.iterdir()]
        return sorted((c for c in found if c), key=lambda c: c.iteration)

    def checkpoint_index(self) -> dict:
        if not self.checkpoints_json.is_file():
            return {}
        try:
            return json.loads(self.checkpoints_json.read_text())
        except json.JSONDecodeError:
            return {}

    def resolve_checkpoint(self, which: str | int | CheckpointInfo = "last") -> CheckpointInfo:
        """`best`, `last`, an iteration number or a `CheckpointInfo` (taken as it is); a clear error when there is
        none."""
        if isinstance(which, CheckpointInfo):
            return which
        cps = self.checkpoints()
        if not cps:
            raise RacerlabError(f"{self.path}: no checkpoints yet; train it first with "
                                f"`racerlab train {shlex.quote(str(self.path))}`")
        if str(which) == "last":
            return cps[-1]  # files are written atomically: the newest one is complete even if the index lags
        if str(which) == "best":
            entry = self.checkpoint_index().get("best_checkpoint", {})
            hit = [c for c in cps if c.name == entry.get("name")]
            return hit[0] if hit else cps[-1]
        try:
            n = int(which)
        except ValueError:
            raise RacerlabError(f"checkpoint must be best, last or an iteration number, got {which!r}") from None
        hit = [c for c in cps if c.iteration == n]
        if not hit:
            raise RacerlabError(f"{self.path}: no checkpoint for iteration {n}; have "
                                f"{', '.join(str(c.iteration) for c in cps)}")
        return hit[0]

    def open(self, checkpoint: str | int | CheckpointInfo = "best") -> OpenModel:
        """The model at `checkpoint` (best, last, an iteration number or a `CheckpointInfo`) for any reader: the
        folder's model_metadata.json and the checkpoint's state, refusing (`ModelRefused`) a checkpoint that cannot
        be read, holds non-finite weights or was trained with an incompatible model_metadata.json (`model.opened`)."""
        return open_model(self, checkpoint)

    def load_state(self, info: CheckpointInfo) -> TrainingState:
        """The checkpoint's `TrainingState` as it is, unchecked (`open` checks it); a file that is not a readable
        racerlab checkpoint is a one-line `ModelRefused`."""
        return TrainingState.from_dict(self.load_checkpoint(info), self.checkpoint_path(info))

    def load_checkpoint(self, info: CheckpointInfo) -> dict:
        """The checkpoint file's dict as it is (`load_state` reads it for you)."""
        import torch

        path = self.checkpoint_path(info)
        try:
            # weights_only: tensors, numbers, strings, lists and dicts — all racerlab writes — and nothing that
            # can run code while it loads (a shared model's checkpoint is someone else's file)
            return torch.load(path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError as exc:
            what = _first_line(exc)
            raise ModelRefused(path, ModelRefused.UNREADABLE, "refused: the checkpoint holds more than racerlab "
                               f"writes (tensors, numbers, strings, lists, dicts): {what}",
                               "only load checkpoints racerlab saved") from None
        except Exception as exc:  # noqa: BLE001 - a damaged file is reported, not a traceback
            raise ModelRefused(path, ModelRefused.UNREADABLE, f"cannot read the checkpoint ({type(exc).__name__}: "
                               f"{_first_line(exc)})", f"it is damaged or incomplete: {self.instead_of(info)}"
                               ) from None

    def instead_of(self, info: CheckpointInfo) -> str:
        """What to open instead of a checkpoint that cannot be used: the newest older one (`--checkpoint N`, as
        evaluate, race, export and clone take it), else another, else none: train again."""
        others = [c.iteration for c in self.checkpoints() if c.iteration != info.iteration]
        older = [n for n in others if n < info.iteration]
        if older:
            return f"pick an older one with --checkpoint {older[-1]}"
        return f"pick another one with --checkpoint {others[-1]}" if others else "train it again"

    def save_state(self, state: TrainingState) -> CheckpointInfo:
        """Write `state` as its iteration's checkpoint (atomically: a kill leaves the previous files whole)."""
        import io

        import torch

        info = state.info
        buf = io.BytesIO()
        torch.save(state.to_dict(), buf)
        atomic_write_bytes(self.checkpoint_path(info), buf.getvalue())
        return info

    def update_index(self, last: CheckpointInfo, last_metric: float, best: CheckpointInfo | None,
                     best_metric: float | None) -> None:
        now = time.time()
        index = {"last_checkpoint": {"name": last.name, "avg_eval_metric": finite_json(last_metric),
                                     "time_stamp": now}}
        if best is not None:
            index["best_checkpoint"] = {"name": best.name, "avg_eval_metric": finite_json(best_metric),
                                        "time_stamp": now}
        atomic_write_json(self.checkpoints_json, index, indent=2)
        # .coach_checkpoint, as AWS keeps it: the current checkpoint's name
        atomic_write_text(self.checkpoints_dir / ".coach_checkpoint", last.name + "\n")

    def prune(self, best: CheckpointInfo | None, keep_last: int = KEEP_LAST) -> None:
        cps = self.checkpoints()
        keep = {c.name for c in cps[-keep_last:]}
        if best is not None:
            keep.add(best.name)
        for c in cps:
            if c.name not in keep:
                self.checkpoint_path(c).unlink(missing_ok=True)

    def drop_after(self, iteration: int) -> None:
        """Remove checkpoints newer than `iteration` (after resuming from an older one)."""
        for c in self.checkpoints():
            if c.iteration > iteration:
                self.checkpoint_path(c).unlink(missing_ok=True)


def _first_line(exc: Exception) -> str:
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    found = next((ln for ln in lines if "GLOBAL" in ln or "Unsupported" in ln), lines[0] if lines else "")
    return found or type(exc).__name__


def resolve_track(folder, track=None, *, default: bool = True):
    """The `Track` a model drives: `track` (a Track, name or file) when given, else the first of the model's
    training tracks (`ModelFolder.tracks`); None when `default` is False and the folder names no track."""
    from racerlab import track as tracks

    if track is not None:
        return tracks.load(track)
    folder = folder if isinstance(folder, ModelFolder) else ModelFolder(folder)
    names = folder.tracks(default)
    return tracks.load(names[0]) if names else None
