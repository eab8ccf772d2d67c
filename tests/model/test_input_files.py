"""A model folder's JSON and TOML files as editors really save them: UTF-16 and BOMs are read, anything that is
not text or is nested absurdly deep is one line naming the file."""

from __future__ import annotations

import json

import pytest

from racerlab.errors import ConfigError
from racerlab.model import init_model, load_training_config


@pytest.fixture
def folder(tmp_path):
    return init_model(tmp_path / "m")


@pytest.mark.parametrize("encoding", ["utf-16", "utf-8-sig", "utf-32"])
def test_metadata_saved_as_utf16_or_with_a_bom_is_read(folder, encoding):
    expected = folder.metadata().to_json()
    folder.metadata_path.write_bytes(json.dumps(json.loads(folder.metadata_path.read_text())).encode(encoding))
    assert folder.metadata().to_json() == expected


@pytest.mark.parametrize("content, message", [
    (b'{"lr": "\xe9\xff"}', "not UTF-8 text"),
    (b"[" * 200_000 + b"]" * 200_000, "nested too deeply"),
])
def test_undecodable_or_absurdly_nested_json_is_one_line(folder, content, message):
    folder.hyperparameters_path.write_bytes(content)
    with pytest.raises(ConfigError) as err:
        folder.hyperparameters()
    assert message in str(err.value) and str(folder.hyperparameters_path) in str(err.value)
    assert "\n" not in str(err.value)


def test_training_toml_with_a_bom_is_read_and_latin1_is_one_line(folder):
    text = folder.config_path.read_text()
    folder.config_path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert load_training_config(folder.config_path).track.names == folder.config().track.names
    folder.config_path.write_bytes(b"# caf\xe9\n" + text.encode())
    with pytest.raises(ConfigError, match="not UTF-8 text"):
        load_training_config(folder.config_path)
