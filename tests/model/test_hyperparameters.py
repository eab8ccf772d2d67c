"""hyperparameters.json parsing: AWS keys, string numbers, defaults and errors that name file and key."""

import json

import pytest

from racerlab.errors import ConfigError
from racerlab.model import Hyperparameters, load_hyperparameters, parse_hyperparameters

DRFC_FILE = {  # DRfC defaults/hyperparameters.json as racers have it
    "batch_size": 64, "beta_entropy": 0.01, "discount_factor": 0.99, "e_greedy_value": 0.05,
    "epsilon_steps": 10000, "exploration_type": "categorical", "loss_type": "huber", "lr": 0.0003,
    "num_episodes_between_training": 20, "num_epochs": 5, "stack_size": 1, "term_cond_avg_score": 350.0,
    "term_cond_max_episodes": 1000, "sac_alpha": 0.2,
}


def test_defaults_follow_the_console():
    hp = parse_hyperparameters({})
    assert hp == Hyperparameters()
    assert (hp.batch_size, hp.discount_factor, hp.loss_type) == (64, 0.99, "huber")
    assert (hp.num_epochs, hp.lr) == (10, 3e-4)
    assert (hp.term_cond_max_episodes, hp.term_cond_avg_score, hp.sac_alpha) == (1000, 350.0, 0.2)


def test_drfc_file_round_trips():
    hp = parse_hyperparameters(DRFC_FILE)
    assert hp.num_epochs == 5
    assert hp.to_json() == DRFC_FILE
    assert parse_hyperparameters(hp.to_json()) == hp


def test_strings_of_numbers_and_case_are_accepted():
    hp = parse_hyperparameters({"lr": "0.0003", "batch_size": "128", "num_epochs": 3.0,
                                "exploration_type": " E-Greedy ", "loss_type": "Mean Squared Error"})
    assert hp.lr == 3e-4 and hp.batch_size == 128 and isinstance(hp.batch_size, int) and hp.num_epochs == 3
    assert hp.exploration_type == "e-greedy" and hp.loss_type == "mean squared error"
    assert parse_hyperparameters({"loss_type": "mse"}).loss_type == "mean squared error"


@pytest.mark.parametrize("data, key", [
    ({"learning_rate": 0.001}, "learning_rate"),
    ({"lr": "fast"}, "lr"),
    ({"lr": 0}, "lr"),
    ({"batch_size": 64.5}, "batch_size"),
    ({"batch_size": True}, "batch_size"),
    ({"num_epochs": 0}, "num_epochs"),
    ({"discount_factor": 1.5}, "discount_factor"),
    ({"e_greedy_value": -0.1}, "e_greedy_value"),
    ({"exploration_type": "softmax"}, "exploration_type"),
    ({"loss_type": 3}, "loss_type"),
    ({"beta_entropy": "nan"}, "beta_entropy"),
    ({"sac_alpha": [0.2]}, "sac_alpha"),
])
def test_errors_name_file_and_key(data, key):
    with pytest.raises(ConfigError) as err:
        parse_hyperparameters(data, "models/m1/hyperparameters.json")
    msg = str(err.value)
    assert msg.startswith("models/m1/hyperparameters.json: ") and key in msg and "\n" not in msg


def test_load_from_file(tmp_path):
    p = tmp_path / "hyperparameters.json"
    p.write_text(json.dumps({"lr": "0.001", "stack_size": 1}))
    hp = load_hyperparameters(p)
    assert hp.lr == 0.001 and hp.source == str(p)
    p.write_text("{not json")
    with pytest.raises(ConfigError, match="invalid JSON"):
        load_hyperparameters(p)
    with pytest.raises(ConfigError, match="file not found"):
        load_hyperparameters(tmp_path / "missing.json")
    p.write_text("[1, 2]")
    with pytest.raises(ConfigError, match="JSON object"):
        load_hyperparameters(p)
