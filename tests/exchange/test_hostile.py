"""Import against hostile and clumsy input: racing imports into one name, memory and disk bombs, symlinks,
poisoned weights, a name that is a file."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
import tarfile

import numpy as np
import pytest

import racerlab
from racerlab.cli import main
from racerlab.errors import ConfigError, RacerlabError
from racerlab.exchange import frozen_graph, import_model
from racerlab.exchange import importer as importer_mod
from racerlab.exchange.graphdef import graph_bytes
from racerlab.exchange.local import open_for_export
from tests.exchange.conftest import make_model

pytest.importorskip("tensorboard", reason="the car's graph protos come with tensorboard")
SRC = os.path.dirname(os.path.dirname(racerlab.__file__))  # the racerlab under test, in the child too


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    """A car model folder (model_metadata.json, agent/model.pb) and its parsed GraphDef."""
    from tensorboard.compat.proto import graph_pb2

    root = tmp_path_factory.mktemp("car")
    model = make_model(root / "m", "camera", "discrete")
    graph = graph_pb2.GraphDef()
    graph.ParseFromString(graph_bytes(frozen_graph(open_for_export(model.path)[1])))
    (root / "car" / "agent").mkdir(parents=True)
    (root / "car" / "model_metadata.json").write_bytes(model.metadata_path.read_bytes())
    (root / "car" / "agent" / "model.pb").write_bytes(graph.SerializeToString())
    return root / "car", graph


def _car_with(tmp_path, car, edit) -> tuple:
    """A copy of the car folder whose model.pb's float constants went through `edit(tensor)`."""
    src, graph = car
    g = type(graph)()
    g.CopyFrom(graph)
    for node in g.node:
        if node.op == "Const" and node.attr["value"].tensor.dtype == 1 and node.name.endswith("kernel"):
            edit(node.attr["value"].tensor)
    dst = tmp_path / "evil"
    shutil.copytree(src, dst)
    (dst / "agent" / "model.pb").write_bytes(g.SerializeToString())
    return dst


def _claim_shape(dims):
    def edit(t):
        from tensorboard.compat.proto import tensor_shape_pb2

        t.ClearField("tensor_content")
        t.float_val[:] = [1.0]
        t.tensor_shape.CopyFrom(tensor_shape_pb2.TensorShapeProto(
            dim=[tensor_shape_pb2.TensorShapeProto.Dim(size=d) for d in dims]))
    return edit


def _pack(folder, out):
    with tarfile.open(out, "w:gz") as tar:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                tar.add(p, p.relative_to(folder).as_posix())
    return out


# ---- 2: two imports into one new name -------------------------------------------------------------------------
def test_an_import_that_loses_the_race_for_a_name_leaves_the_winners_folder(tmp_path, car, monkeypatch):
    out = tmp_path / "twin"
    real = importer_mod.write_imported_model
    calls = []

    def racing(dst, *args, **kw):
        if not calls:  # the other `racerlab import` finishes first, while this one is still converting
            calls.append(1)
            import_model(car[0], out)
            assert (out / "checkpoints" / "0_Step-0.pt").is_file()
        return real(dst, *args, **kw)

    monkeypatch.setattr(importer_mod, "write_imported_model", racing)
    winner = None
    with pytest.raises(RacerlabError, match="twin") as err:
        import_model(car[0], out)
    winner = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    assert "\n" not in str(err.value)
    assert "checkpoints/0_Step-0.pt" in winner and "model_metadata.json" in winner  # the winner's folder is whole
    assert [p.name for p in tmp_path.iterdir()] == ["twin"]  # and no staging folder is left


def test_a_failed_import_leaves_nothing_at_the_name(tmp_path, car):
    bad = _car_with(tmp_path, car, _claim_shape([3, 3]))
    with pytest.raises(ConfigError):
        import_model(bad, tmp_path / "new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["evil"]


# ---- 3: shapes checked before anything is allocated ------------------------------------------------------------
def test_a_graphdef_memory_bomb_is_refused_under_a_memory_cap(tmp_path, car):
    """A Const that claims [40000, 40000] (6.4 GB of float32) in a few hundred bytes."""
    archive = _pack(_car_with(tmp_path, car, _claim_shape([40000, 40000])), tmp_path / "bomb.tar.gz")
    code = ("import resource, sys\nfrom racerlab.cli import main\nimport racerlab.exchange.importer, torch\n"
            "with open('/proc/self/statm') as f:\n    used = int(f.read().split()[0]) * resource.getpagesize()\n"
            "cap = used + (1 << 30)\nresource.setrlimit(resource.RLIMIT_AS, (cap, cap))\n"
            f"sys.exit(main(['import', {str(archive)!r}, {str(tmp_path / 'out')!r}]))\n")
    env = {**os.environ, "PYTHONPATH": os.path.abspath(SRC)}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 2, r.stderr[-2000:]
    assert "claims shape [40000, 40000]" in r.stderr and r.stderr.count("\n") == 1, r.stderr[-2000:]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("dims", [[-1, 5], [2**62, 2**62, 16], [1] * 20])
def test_negative_overflowing_or_deep_shapes_are_one_line(tmp_path, car, dims):
    bad = _car_with(tmp_path, car, _claim_shape(dims))
    with pytest.raises(ConfigError, match=r"model\.pb: constant .*shape") as err:
        import_model(bad, tmp_path / "out")
    assert "\n" not in str(err.value)


# ---- 13: poisoned weights ---------------------------------------------------------------------------------------
def test_nan_weights_are_refused_naming_the_variable(tmp_path, car, capsys):
    def poison(t):
        a = np.frombuffer(t.tensor_content, "<f4").copy()
        a[0] = np.nan
        t.tensor_content = a.tobytes()

    bad = _car_with(tmp_path, car, poison)
    assert main(["import", str(bad), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "NaN or infinite" in err and "kernel" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


# ---- 9: disk amplification --------------------------------------------------------------------------------------
def test_members_the_importer_does_not_read_are_never_written(tmp_path, car):
    folder = tmp_path / "padded"
    shutil.copytree(car[0], folder)
    (folder / "junk.bin").write_bytes(bytes(32 << 20))  # 32 MiB of zeros: a few KiB gzipped
    archive = _pack(folder, tmp_path / "padded.tar.gz")
    assert archive.stat().st_size < (folder / "agent" / "model.pb").stat().st_size + (1 << 20)
    dest = tmp_path / "unpacked"
    importer_mod.safe_extract(archive, dest)
    assert sorted(p.relative_to(dest).as_posix() for p in dest.rglob("*") if p.is_file()) == [
        "agent/model.pb", "model_metadata.json"]


@pytest.mark.skipif(shutil.which("tar") is None, reason="GNU tar writes sparse members")
def test_a_sparse_member_is_refused_before_it_is_written(tmp_path, car):
    folder = tmp_path / "sparse"
    shutil.copytree(car[0], folder)
    with open(folder / "reward_function.py", "wb") as f:
        f.truncate(64 << 20)  # 64 MiB of holes
    archive = tmp_path / "sparse.tar.gz"
    subprocess.run(["tar", "-czSf", str(archive), "-C", str(folder), "."], check=True)
    assert archive.stat().st_size < (folder / "agent" / "model.pb").stat().st_size + (1 << 20)
    with pytest.raises(ConfigError, match="reward_function.py") as err:
        import_model(archive, tmp_path / "out")
    assert "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()


def test_an_oversized_text_file_is_refused(tmp_path, car):
    folder = tmp_path / "big"
    shutil.copytree(car[0], folder)
    (folder / "hyperparameters.json").write_bytes(b" " * (2 << 20) + b"{}")
    with pytest.raises(ConfigError, match="hyperparameters.json"):
        importer_mod.safe_extract(_pack(folder, tmp_path / "big.tar.gz"), tmp_path / "unpacked")
    assert not (tmp_path / "unpacked" / "hyperparameters.json").exists()


def test_too_many_members_are_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(importer_mod, "MAX_MEMBERS", 10, raising=False)
    archive = tmp_path / "many.tar"
    with tarfile.open(archive, "w") as tar:
        for k in range(11):
            info = tarfile.TarInfo(f"f{k}.txt")
            info.size = 1
            tar.addfile(info, io.BytesIO(b"x"))
    with pytest.raises(ConfigError, match="more than 10 members"):
        importer_mod.safe_extract(archive, tmp_path / "unpacked")


# ---- 10: symbolic links -----------------------------------------------------------------------------------------
def test_a_folder_import_never_follows_a_symlink(tmp_path, car):
    secret = tmp_path / "secret.txt"
    secret.write_text("root:hash:19000:0:99999:7:::\n")
    folder = tmp_path / "linked"
    shutil.copytree(car[0], folder)
    (folder / "reward_function.py").symlink_to(secret)
    with pytest.raises(ConfigError, match="symbolic link") as err:
        import_model(folder, tmp_path / "out")
    assert str(folder / "reward_function.py") in str(err.value)
    assert not (tmp_path / "out").exists()


# ---- 12: the destination is a file ------------------------------------------------------------------------------
def test_an_import_name_that_is_a_file_is_one_line(tmp_path, car, capsys):
    (tmp_path / "taken").write_text("notes\n")
    assert main(["import", str(car[0]), str(tmp_path / "taken")]) == 2
    err = capsys.readouterr().err
    assert "a file of that name exists" in err and err.count("\n") == 1
    assert (tmp_path / "taken").read_text() == "notes\n"


def test_an_import_still_works_into_an_empty_folder(tmp_path, car):
    (tmp_path / "empty").mkdir()
    out = import_model(car[0], tmp_path / "empty")
    assert json.loads((out / "lineage.json").read_text())["imported"]["weights"] == "model.pb"


# ---- 8, 12: S3 pull into a folder that has files; bad endpoints, profiles and keys ----------------------------------
def _dead_pid() -> int:
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    return gone.pid


def test_pull_refuses_a_folder_with_files_unless_forced(s3_server, tmp_path, capsys):
    s3_server.put_object(Bucket="races", Key="m/reward_function.py", Body=b"def reward_function(p):\n    return 2.0\n")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "reward_function.py").write_text("my own reward\n")
    assert main(["s3", "pull", "s3://races/m", str(mine)]) == 2
    err = capsys.readouterr().err
    assert "not empty" in err and "--force" in err and err.count("\n") == 1
    assert (mine / "reward_function.py").read_text() == "my own reward\n"
    assert main(["s3", "pull", "s3://races/m", str(mine), "--force"]) == 0
    assert "return 2.0" in (mine / "reward_function.py").read_text()


def test_a_killed_pulls_part_files_are_removed_and_do_not_count_as_files(s3_server, tmp_path):
    s3_server.put_object(Bucket="races", Key="m/model_metadata.json", Body=b"{}")
    dest = tmp_path / "pulled"
    (dest / "model").mkdir(parents=True)
    stale = dest / "model" / f".model_3.pb.part-{_dead_pid()}-k2j4"
    stale.write_bytes(bytes(1000))
    assert main(["s3", "pull", "s3://races/m", str(dest)]) == 0
    assert not stale.exists() and (dest / "model_metadata.json").read_bytes() == b"{}"


@pytest.mark.parametrize("keys, message", [
    (["m/a", "m/a/b"], "both an object and a folder"),
    (["m/" + "x" * 300], "too long for a file name"),
])
def test_keys_that_cannot_be_files_are_one_line_before_any_write(s3_server, tmp_path, capsys, keys, message):
    for k in keys:
        s3_server.put_object(Bucket="races", Key=k, Body=b"1")
    assert main(["s3", "pull", "s3://races/m", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not any((tmp_path / "p").rglob("*")) if (tmp_path / "p").exists() else True


@pytest.mark.parametrize("flags, message", [
    (["--endpoint-url", "localhost:9000"], "--endpoint-url localhost:9000: not an http(s) URL"),
    (["--profile", "no-such-profile-here"], "--profile no-such-profile-here: no such profile"),
])
def test_bad_endpoint_or_profile_is_one_line(tmp_path, capsys, monkeypatch, flags, message):
    pytest.importorskip("boto3")
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "config"))
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "credentials"))
    assert main(["s3", "pull", "s3://races/m", str(tmp_path / "p"), *flags]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
