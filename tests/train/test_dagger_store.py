"""DAgger's data set kept beside the checkpoints (`train.dagger_store`): it gives back the set as of a checkpoint,
holds at most about twice the set on disk, and a damaged, foreign or hostile file is one line, read without pickle
and without a huge allocation."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from racerlab.agent.imitate import Demonstrations
from racerlab.train.dagger_store import DaggerStore, StoreError

COLUMNS = {"camera": ((2, 3), np.dtype(np.uint8)), "teacher:features": ((4,), np.dtype(np.float32))}


def _steps(rng, n):
    return {"camera": rng.integers(0, 255, (n, 2, 3), dtype=np.uint8),
            "teacher:features": rng.normal(size=(n, 4)).astype(np.float32)}


def _keep(store, demos, iteration, steps):
    demos.add(steps)
    store.save(iteration, demos.columns, demos.size, demos.last_rows, {"seen": demos.seen,
               "rng": demos.rng.bit_generator.state}, {"s.0.exp_avg": np.full(3, float(iteration))}, {"rate": 0.1})


def test_the_set_comes_back_as_of_each_checkpoint_and_the_store_stays_bounded(tmp_path):
    rng = np.random.default_rng(0)
    store, demos = DaggerStore(tmp_path / "dagger", COLUMNS, 10, fit_bytes=100), Demonstrations(10, seed=1)
    sets = {}
    for it, n in enumerate([4, 3, 2, 6, 5], 1):  # full after iteration 3: then new rows replace random old ones
        _keep(store, demos, it, _steps(rng, n))
        sets[it] = {k: demos.column(k).copy() for k in COLUMNS}
        on_disk = sum(len(np.load(p)["slots"]) for _, p in store.files())
        assert on_disk <= 2 * 10  # at most about twice the set (a snapshot and the rows since)
    assert [it for it, _ in store.files()][0] > 1  # compacted: the first files were replaced by a snapshot
    again = DaggerStore(tmp_path / "dagger", COLUMNS, 10, fit_bytes=100)
    loaded = again.load(5)
    assert loaded.size == 10 and loaded.seen == 20 and float(loaded.fit["s.0.exp_avg"][0]) == 5.0
    for k in COLUMNS:
        np.testing.assert_array_equal(loaded.columns[k][:loaded.size], sets[5][k])
    oldest = store.files()[0][0]
    loaded = again.load(oldest)  # resuming from an older checkpoint forgets the files after it
    assert [it for it, _ in again.files()] == [oldest]
    for k in COLUMNS:
        np.testing.assert_array_equal(loaded.columns[k][:loaded.size], sets[oldest][k])


def _npz(path, **arrays):
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def _meta(**over):
    return np.array(json.dumps({"format": "racerlab.dagger/1", "iteration": 1, "capacity": 10, "size": 2,
                                "snapshot": True, "columns": sorted(COLUMNS), "seen": 2, "rng": {}, "fit": {},
                                **over}))


def _huge_header_zip(path):
    """An .npz whose array declares 10**12 float64 rows and holds 8 bytes."""
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f8", "fortran_order": False, "shape": (10**12, 4)})
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("col1.npy", head.getvalue() + b"\0" * 8)


@pytest.mark.parametrize("make, says", [
    (lambda p: p.write_bytes(b"PK\x03\x04 cut short"), "not a readable DAgger data set file"),
    (lambda p: _npz(p, meta=_meta(format="other/1"), slots=np.arange(2)), "not a racerlab DAgger data set file"),
    (lambda p: _npz(p, meta=_meta(), slots=np.arange(2), col0=np.zeros((2, 5, 5), np.uint8),
                    col1=np.zeros((2, 4), np.float32)), "has rows of (5, 5)"),
    (lambda p: _npz(p, meta=_meta(), slots=np.array([0, 7]), col0=np.zeros((2, 2, 3), np.uint8),
                    col1=np.zeros((2, 4), np.float32)), "slots are not rows"),
    (lambda p: _npz(p, meta=_meta(), slots=np.arange(2), col0=np.zeros((2, 2, 3), np.uint8),
                    col1=np.full((2, 4), np.nan, np.float32)), "non-finite"),
    (lambda p: _npz(p, meta=_meta(), slots=np.array([object(), 1], dtype=object)), "not what it holds"),
    (_huge_header_zip, "declares (1000000000000, 4)"),
])
def test_a_damaged_foreign_or_hostile_file_is_one_line(tmp_path, make, says):
    store = DaggerStore(tmp_path / "dagger", COLUMNS, 10, fit_bytes=100)
    store.path.mkdir()
    make(store.path / "1.npz")
    with pytest.raises(StoreError) as err:
        store.load(1)
    assert says in str(err.value) and "\n" not in str(err.value) and str(store.path / "1.npz") in str(err.value)
