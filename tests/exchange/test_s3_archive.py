"""S3 push/pull against a real S3-compatible HTTP server (moto's server on 127.0.0.1), and archive safety."""

from __future__ import annotations

import io
import tarfile

import pytest

from racerlab.cli import main
from racerlab.errors import ConfigError
from racerlab.exchange import import_model
from tests.exchange.conftest import make_model


def test_push_pull_round_trip_multipart_checksums_and_rerun(s3_server, tmp_path, capsys):
    folder = make_model(tmp_path / "m", "camera", "discrete")
    assert main(["s3", "push", str(folder.path), "s3://races/drfc/mine"]) == 0
    keys = {o["Key"]: o["Size"] for o in s3_server.list_objects_v2(Bucket="races", Prefix="drfc/mine/")["Contents"]}
    data_key = "drfc/mine/model/3_Step-1200.ckpt.data-00000-of-00001"
    assert keys[data_key] > 8 << 20 and "drfc/mine/model/model_3.pb" in keys and "drfc/mine/reward_function.py" in keys
    assert s3_server.head_object(Bucket="races", Key=data_key)["ETag"].strip('"').endswith("-" + str(
        -(-keys[data_key] // (8 << 20))))  # a multipart ETag: md5-of-parts "-" part count

    # a second push finds the big files in place and skips them
    assert main(["s3", "push", str(folder.path), "s3://races/drfc/mine"]) == 0
    assert "already there" in capsys.readouterr().out

    assert main(["s3", "pull", "s3://races/drfc/mine", str(tmp_path / "pulled")]) == 0
    assert (tmp_path / "pulled" / "model" / "3_Step-1200.ckpt.index").is_file()
    assert main(["import", str(tmp_path / "pulled"), str(tmp_path / "back")]) == 0
    assert (tmp_path / "back" / "checkpoints" / "0_Step-0.pt").is_file()

    # a corrupted object is caught by the SHA-256 check on pull
    s3_server.put_object(Bucket="races", Key="drfc/mine/reward_function.py", Body=b"tampered",
                         Metadata={"racerlab-sha256": "0" * 64})
    assert main(["s3", "pull", "s3://races/drfc/mine", str(tmp_path / "pulled2")]) == 2
    assert "does not match the object's SHA-256" in capsys.readouterr().err


def test_pull_from_a_missing_bucket_is_one_line(s3_server, tmp_path, capsys):
    assert main(["s3", "pull", "s3://nobucket/x", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert "s3://nobucket/x" in err and err.count("\n") == 1


def _tar_with(tmp_path, name: str, link: bool = False):
    path = tmp_path / "evil.tar.gz"
    with tarfile.open(path, "w:gz") as tar:
        ok = tarfile.TarInfo("model_metadata.json")
        ok.size = 2
        tar.addfile(ok, io.BytesIO(b"{}"))
        bad = tarfile.TarInfo(name)
        if link:
            bad.type, bad.linkname = tarfile.SYMTYPE, "/etc/passwd"
        else:
            bad.size = 1
        tar.addfile(bad, None if link else io.BytesIO(b"x"))
    return path


@pytest.mark.parametrize("name,link", [("../escape.py", False), ("/abs/reward_function.py", False),
                                       ("model/a/../../../x", False), ("agent/model.pb", True)])
def test_archives_with_escaping_members_are_refused_before_writing(tmp_path, monkeypatch, name, link):
    monkeypatch.chdir(tmp_path)
    archive = _tar_with(tmp_path, name, link)
    with pytest.raises(ConfigError, match="refusing to extract"):
        import_model(archive, tmp_path / "out")
    assert not (tmp_path / "out").exists() and not (tmp_path / "escape.py").exists()


def test_a_corrupt_model_pb_is_one_line_naming_the_file(tmp_path):
    folder = make_model(tmp_path / "m", "camera", "discrete")
    (tmp_path / "car" / "agent").mkdir(parents=True)
    (tmp_path / "car" / "model_metadata.json").write_bytes(folder.metadata_path.read_bytes())
    (tmp_path / "car" / "agent" / "model.pb").write_bytes(b"\xff\xfe garbage")
    with pytest.raises(ConfigError, match=r"agent/model\.pb: not a TensorFlow GraphDef"):
        import_model(tmp_path / "car", tmp_path / "out")


def test_an_unknown_network_names_the_supported_ones(tmp_path):
    folder = make_model(tmp_path / "m", "camera", "discrete")
    meta = folder.metadata_path.read_text().replace("DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "RESNET_50")
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "model_metadata.json").write_text(meta)
    (tmp_path / "x" / "model.pb").write_bytes(b"")
    with pytest.raises(ConfigError, match=r"neural_network must be one of .*DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"):
        import_model(tmp_path / "x", tmp_path / "out")
