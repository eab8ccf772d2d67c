"""A training checkpoint, `checkpoints/<N>_Step-<S>.pt`: the one place that knows its file name and its keys.

`CheckpointInfo` is a file's name, iteration N and training steps S (AWS's scheme, facts §9; N = 0 before any
training). `TrainingState` is what the file holds: the agent's weights, the model_metadata.json and
hyperparameters they were trained with, the observation, the run's counters, the collection's resume state
and the best checkpoint so far. Every writer (training, clone, import) builds one and every reader gets one
from `ModelFolder.open` (which reads it with `ModelFolder.load_state`); nothing else reads the dict's keys.
`nonfinite_tensors` finds the weights that hold NaN or infinity.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field, fields, replace

from racerlab.errors import ModelRefused

CHECKPOINT_FORMAT = "racerlab.checkpoint/1"
CHECKPOINT_RE = re.compile(r"^(\d+)_Step-(\d+)\.pt$")
# in an agent state, marks one that holds the networks' weights alone (a race server's stored model): a reader of
# greedy actions takes the rest from a freshly built agent (`racerlab.agent.inference_policy`)
WEIGHTS_ONLY_KEY = "weights_only"


@dataclass(frozen=True)
class CheckpointInfo:
    name: str
    iteration: int
    steps: int

    @classmethod
    def parse(cls, name: str) -> CheckpointInfo | None:
        m = CHECKPOINT_RE.match(name)
        return cls(name, int(m.group(1)), int(m.group(2))) if m else None

    @classmethod
    def of(cls, iteration: int, steps: int) -> CheckpointInfo:
        """The checkpoint of iteration `iteration` after `steps` training steps."""
        return cls(f"{iteration}_Step-{steps}.pt", iteration, steps)


@dataclass
class TrainingState:
    """The contents of one training checkpoint."""

    agent: dict  # the agent's `state_dict()` (PPO or SAC: it carries its own format)
    metadata: dict | None = None  # model_metadata.json the weights were trained with (as JSON)
    hyperparameters: dict | None = None  # hyperparameters.json at the time (None: older racerlab, or a clone)
    observation: str | None = None  # run.observation the network's inputs were built for
    iteration: int = 0
    episodes: int = 0
    env_steps: int = 0
    train_steps: int | None = None  # learned-on steps, the S of N_Step-S (None: take the file name's)
    best_name: str | None = None
    best_metric: float | None = None
    # "laptime": the fastest mean evaluation lap so far, which the best checkpoint (the newest within one step's tie
    # of it: `train.evaluation.laptime_tie_ms`) is measured from (None: older racerlab, or another metric)
    best_floor: float | None = None
    best_rule: str | None = None  # the [evaluation] best_model_metric best_name and best_metric are by (None: older)
    best_lap_time: float = math.nan
    best_lap_iteration: int | None = None  # the iteration whose evaluation drove best_lap_time
    rollbacks: int = 0
    first_lap: dict | None = None  # iteration, wall and CPU seconds and env steps of the first completed eval lap
    # what the collection keeps to resume (`train.seams.Collection.state`: a local run's round-robin counters, a
    # cluster's per-worker episode counts, a taught run's teacher seconds), under the collection's own keys, kept
    # flat in the file as racerlab has always written them: every key of the file that is not one of these fields
    collection: dict = field(default_factory=dict)
    cloned: bool = False  # cloned or imported: training goes on from these weights with fresh counters
    saved_at: float = 0.0

    def to_dict(self) -> dict:
        """The dict the file holds."""
        out = {"format": CHECKPOINT_FORMAT, **{f.name: getattr(self, f.name) for f in fields(self)}}
        del out["collection"]
        out.update({k: v for k, v in self.collection.items() if k not in out})
        out["saved_at"] = self.saved_at or time.time()
        if not self.cloned:
            del out["cloned"]
        return out

    @classmethod
    def from_dict(cls, data, where) -> TrainingState:
        """A checkpoint's state; `where` (its path) names it in the one-line `ModelRefused` for a file without agent
        weights or of another format."""
        if not isinstance(data, dict) or not isinstance(data.get("agent"), dict):
            raise ModelRefused(where, ModelRefused.UNREADABLE, "not a racerlab checkpoint (no agent weights in it)",
                               "only open checkpoints racerlab saved")
        if data.get("format") != CHECKPOINT_FORMAT:
            raise ModelRefused(where, ModelRefused.UNREADABLE, f"a checkpoint of format {data.get('format')!r}, and "
                               f"this racerlab reads {CHECKPOINT_FORMAT!r}", "train a new one or use the racerlab that "
                               "wrote it")
        known = {f.name for f in fields(cls)} - {"collection"}
        state = cls(**{k: v for k, v in data.items() if k in known and v is not None})
        state.collection = {k: v for k, v in data.items() if k not in known and k != "format" and v is not None}
        return state

    @property
    def info(self) -> CheckpointInfo:
        """The file this state is saved as."""
        return CheckpointInfo.of(self.iteration, self.train_steps or 0)

    def cloned_as(self, metadata: dict) -> TrainingState:
        """This state as the first checkpoint of a clone with `metadata`: the weights and counters stay, the best
        checkpoint, rollbacks and round-robin state start afresh."""
        return replace(self, cloned=True, best_name=None, best_metric=None, best_floor=None, best_rule=None,
                       rollbacks=0, collection={}, metadata=metadata, saved_at=0.0)


def nonfinite_tensors(state, prefix: str = "") -> list[str]:
    """Names (dotted paths) of the floating-point tensors in a checkpoint that hold NaN or infinity."""
    import torch

    if isinstance(state, torch.Tensor):
        bad = state.is_floating_point() and not bool(torch.isfinite(state).all())
        return [prefix] if bad else []
    items = state.items() if isinstance(state, dict) else enumerate(state) if isinstance(state, list | tuple) else ()
    return [name for k, v in items for name in nonfinite_tensors(v, f"{prefix}.{k}" if prefix else str(k))]
