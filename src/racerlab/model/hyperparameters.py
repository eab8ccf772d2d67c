"""`hyperparameters.json`: the AWS training hyperparameters of a model, as a frozen dataclass.

Keys and meanings are the AWS simulator's (facts §6, SIM `sagemaker_graph_manager.py`
`get_updated_hyper_parameters`). Values may be JSON numbers or strings of numbers ("0.0003"), as AWS
parses them with `int(...)`/`float(...)`; string options are compared lower-cased and stripped, as AWS does.

Defaults, where the sources disagree (facts §6 table and §12.12): we follow the DeepRacer-on-AWS (DRoA)
console, the open-source successor of the managed console, for every key it sets (batch_size 64,
beta_entropy 0.01, discount_factor 0.99, categorical, huber, lr 0.0003, 20 episodes, num_epochs 10,
sac_alpha 0.2), and the DRfC `defaults/hyperparameters.json` for the keys DRoA leaves out (e_greedy_value
0.05, epsilon_steps 10000, stack_size 1, term_cond_max_episodes 1000, term_cond_avg_score 350). Note that
the simulator's own fall-backs differ (discount 0.999, mean squared error): a file that omits a key trains
here like a console model, not like a bare simapp.

Unlike AWS, which ignores unknown keys, an unknown key is a `ConfigError`: a misspelt "learning_rate"
should not silently train with the default.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from racerlab.errors import ConfigError
from racerlab.model.metadata import parse_number, read_json_file

EXPLORATION_TYPES = ("categorical", "e-greedy", "additive_noise")
LOSS_TYPES = ("huber", "mean squared error")
# Spellings community tools write for the same loss; AWS treats anything but "huber" as MSE.
_LOSS_ALIASES = {"mse": "mean squared error", "mean_squared_error": "mean squared error"}


@dataclass(frozen=True)
class Hyperparameters:
    """Training hyperparameters, AWS key names. `source` names the file for error messages."""

    batch_size: int = 64
    beta_entropy: float = 0.01
    discount_factor: float = 0.99
    e_greedy_value: float = 0.05
    epsilon_steps: int = 10000
    exploration_type: str = "categorical"
    loss_type: str = "huber"
    lr: float = 0.0003
    num_episodes_between_training: int = 20
    num_epochs: int = 10
    stack_size: int = 1  # accepted and ignored, as AWS (frame stacking is fixed at 1, facts §4)
    term_cond_max_episodes: int = 1000
    term_cond_avg_score: float = 350.0  # parsed but unused by AWS; racerlab's train may use it
    sac_alpha: float = 0.2
    source: str = dataclasses.field(default="hyperparameters.json", compare=False)

    def to_json(self) -> dict:
        """The AWS `hyperparameters.json` dict (without `source`)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "source"}

    def replace(self, **changes) -> Hyperparameters:
        return dataclasses.replace(self, **changes)


# key -> (kind, lowest allowed, highest allowed); kinds: "int", "float", "choice"
_RULES: dict[str, tuple[str, float | None, float | None]] = {
    "batch_size": ("int", 1, None),
    "beta_entropy": ("float", 0.0, None),
    "discount_factor": ("float", 0.0, 1.0),
    "e_greedy_value": ("float", 0.0, 1.0),
    "epsilon_steps": ("int", 0, None),
    "exploration_type": ("choice", None, None),
    "loss_type": ("choice", None, None),
    "lr": ("float", 0.0, None),
    "num_episodes_between_training": ("int", 1, None),
    "num_epochs": ("int", 1, None),
    "stack_size": ("int", 1, None),
    "term_cond_max_episodes": ("int", 1, None),
    "term_cond_avg_score": ("float", None, None),
    "sac_alpha": ("float", 0.0, None),
}
_CHOICES = {"exploration_type": EXPLORATION_TYPES, "loss_type": LOSS_TYPES}


_as_float = parse_number


def _as_int(src: str, key: str, value) -> int:
    x = _as_float(src, key, value)
    if not x.is_integer():
        raise ConfigError(f"{src}: {key} must be a whole number, got {value!r}")
    return int(x)


def _as_choice(src: str, key: str, value) -> str:
    allowed = _CHOICES[key]
    if not isinstance(value, str):
        raise ConfigError(f"{src}: {key} must be one of {', '.join(map(repr, allowed))}, got {value!r}")
    v = value.lower().strip()
    v = _LOSS_ALIASES.get(v, v) if key == "loss_type" else v
    if v not in allowed:
        raise ConfigError(f"{src}: {key} must be one of {', '.join(map(repr, allowed))}, got {value!r}")
    return v


def _check_range(src: str, key: str, x: float, lo: float | None, hi: float | None) -> None:
    # Lower bounds are inclusive except for lr, where 0 would silently train nothing.
    if key == "lr" and x <= 0:
        raise ConfigError(f"{src}: lr must be > 0, got {x}")
    if lo is not None and x < lo:
        raise ConfigError(f"{src}: {key} must be >= {lo}, got {x}")
    if hi is not None and x > hi:
        raise ConfigError(f"{src}: {key} must be <= {hi}, got {x}")


def parse_hyperparameters(data: dict, source: str = "hyperparameters.json") -> Hyperparameters:
    """Validate a hyperparameters dict; missing keys take the documented defaults."""
    src = source
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: expected a JSON object, got {type(data).__name__}")
    unknown = sorted(set(data) - set(_RULES))
    if unknown:
        raise ConfigError(f"{src}: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(_RULES))}")
    values = {}
    for key, raw in data.items():
        kind, lo, hi = _RULES[key]
        if kind == "choice":
            values[key] = _as_choice(src, key, raw)
            continue
        x = _as_int(src, key, raw) if kind == "int" else _as_float(src, key, raw)
        _check_range(src, key, x, lo, hi)
        values[key] = x
    return Hyperparameters(**values, source=src)


def load_hyperparameters(path) -> Hyperparameters:
    return parse_hyperparameters(read_json_file(path), str(path))
