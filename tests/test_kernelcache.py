"""numba's compiled-kernel cache (`racerlab.kernelcache`): one owned folder per fingerprint of the compiled sources,
never numba's cache beside the sources, damaged entries cleared with one line, pruning of its own entries only.

Each case runs in a fresh process (the cache is chosen at `import racerlab`, before numba loads) with its own
cache folders, compiling one small kernel of a copy of the package where a case watches the source tree.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

import racerlab

PACKAGE = Path(racerlab.__file__).parent
# one small kernel of racerlab's, compiled and called
KERNEL = ("import racerlab\nfrom racerlab.track.kernels import segment_distance_sq\n"
          "print(segment_distance_sq(0.5, 0.2, 0.0, 0.0, 1.0, 0.0, 1.0))\n")
ANSWER = "(0.04000000000000001, 0.5)"


def _run(tmp_path: Path, code: str = KERNEL, package: Path = PACKAGE, **env) -> subprocess.CompletedProcess:
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "RACERLAB_KERNEL"))}
    clean.update({"PYTHONPATH": str(package.parent), "XDG_CACHE_HOME": str(tmp_path / "cache"),
                  "TMPDIR": str(_tmp(tmp_path)), "HOME": str(tmp_path / "home")}, **env)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=clean, timeout=240,
                          cwd=tmp_path)


def _tmp(tmp_path: Path) -> Path:
    (tmp_path / "tmp").mkdir(exist_ok=True)
    return tmp_path / "tmp"


def _copy(tmp_path: Path) -> Path:
    """A copy of the package, to see whether anything is written beside its sources."""
    copy = tmp_path / "src" / "racerlab"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    return copy


def _in_tree(copy: Path) -> list[str]:
    return sorted(p.name for p in copy.rglob("*") if p.suffix in (".nbi", ".nbc"))


def _entries(root: Path) -> list[Path]:
    return sorted(root.rglob("*.nbi"))


def test_kernels_go_to_the_users_cache_one_folder_per_fingerprint(tmp_path):
    from racerlab import kernelcache

    code = "import os, racerlab, numba; print(os.environ['NUMBA_CACHE_DIR']); print(numba.config.CACHE_DIR)"
    out = _run(tmp_path, code + "; print(os.environ.get('NUMBA_CACHE_LOCATOR_CLASSES'))")
    key = kernelcache.sources_key()
    # the fingerprint's folder, and nothing in the environment that names racerlab to other programs numba runs
    assert len(key) == 16 and out.stdout.split() == [str(tmp_path / "cache" / "racerlab" / "numba" / key)] * 2 + [
        "None"]
    out = _run(tmp_path, code + "\n" + KERNEL, NUMBA_CACHE_DIR=str(tmp_path / "mine"))
    assert out.stdout.split()[:2] == [str(tmp_path / "mine")] * 2  # the user's choice is kept ...
    assert _entries(tmp_path / "mine" / f"racerlab-{key}")  # ... and holds the fingerprint's folder


def test_a_change_to_any_compiled_source_gets_a_fresh_cache(tmp_path):
    """numba checks a cached kernel against its own file only: the simulator's step, which calls the car's compiled
    functions, kept the car before a refit. The cache folder is named by all compiled sources together."""
    from racerlab import kernelcache

    package = tmp_path / "racerlab"
    shutil.copytree(PACKAGE, package, ignore=shutil.ignore_patterns("__pycache__", "data"))
    key = kernelcache.sources_key(str(package))
    assert key == kernelcache.sources_key()  # the same sources, wherever they are
    with open(package / "cli" / "quickstart.py", "a") as fh:  # no compiled code in it
        fh.write("# a comment\n")
    assert kernelcache.sources_key(str(package)) == key
    with open(package / "sim" / "car.py", "a") as fh:  # the car's compiled functions
        fh.write("# a comment\n")
    assert kernelcache.sources_key(str(package)) != key


@pytest.mark.parametrize("first", ["", "import numba, numba.core.caching\n"], ids=["racerlab-first", "numba-first"])
def test_an_unusable_cache_folder_goes_to_a_folder_of_ones_own_never_beside_the_sources(tmp_path, first):
    """Issue 45, item 3: with the cache folder unusable (here a file) numba fell back to its cache beside the sources,
    which ran stale compiled code. Also when numba was imported before racerlab."""
    copy = _copy(tmp_path)
    (tmp_path / "cache").write_text("not a folder")
    out = _run(tmp_path, first + KERNEL + "import os; print(os.environ['NUMBA_CACHE_DIR'])", package=copy)
    assert out.returncode == 0, out.stderr
    answer, where = out.stdout.split("\n")[:2]
    assert answer == ANSWER and _in_tree(copy) == []
    own = _tmp(tmp_path) / f"racerlab-{os.getuid()}"
    assert Path(where).is_relative_to(own) and _entries(own) and (own.stat().st_mode & 0o777) == 0o700


def test_a_temporary_folder_someone_else_could_hold_is_not_used(tmp_path):
    """The fallback is this user's own 0700 folder: a name in the temporary folder that is a link, or open to others,
    could hand the kernels this process runs to someone else."""
    copy = _copy(tmp_path)
    (tmp_path / "cache").write_text("not a folder")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (_tmp(tmp_path) / f"racerlab-{os.getuid()}").symlink_to(elsewhere)
    out = _run(tmp_path, package=copy)
    assert out.returncode == 0 and out.stdout.strip() == ANSWER, out.stderr
    assert list(elsewhere.iterdir()) == [] and _in_tree(copy) == []
    assert "no writable folder for compiled kernels" in out.stderr and out.stderr.count("\n") == 1


def test_with_no_writable_folder_the_kernels_compile_in_every_run_with_one_line(tmp_path):
    """Issue 45, item 3: a read-only install with no writable cache ended in numba's `no locator available`; racerlab's
    kernels never go beside the sources, and without any folder to keep them they compile each time."""
    copy = _copy(tmp_path)
    (tmp_path / "cache").write_text("not a folder")
    (_tmp(tmp_path) / f"racerlab-{os.getuid()}").write_text("taken")
    for _ in range(2):
        out = _run(tmp_path, package=copy)
        assert out.returncode == 0 and out.stdout.strip() == ANSWER, out.stderr
        lines = out.stderr.strip().splitlines()
        assert len(lines) == 1 and "no writable folder for compiled kernels" in lines[0]
        assert "set NUMBA_CACHE_DIR" in lines[0] and _in_tree(copy) == []


@pytest.mark.parametrize("damage", ["index", "data"])
def test_a_damaged_entry_is_cleared_and_compiled_again_with_one_line(tmp_path, damage):
    """Issue 45, item 3: a damaged cache file gave an Unpickling, EOF or Overflow traceback on every command."""
    assert _run(tmp_path).stdout.strip() == ANSWER
    (index,) = _entries(tmp_path / "cache")
    (data,) = index.parent.glob(index.name[:-len(".nbi")] + ".*.nbc")
    if damage == "index":
        index.write_bytes(os.urandom(40))
    else:
        data.write_bytes(data.read_bytes()[:100])  # cut short, as a full disk or a killed write leaves it
    out = _run(tmp_path)
    assert out.returncode == 0 and out.stdout.strip() == ANSWER, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "compiled-kernel cache entry" in lines[0] and "was damaged" in lines[0]
    assert "compiling it again" in lines[0] and "Traceback" not in out.stderr
    again = _run(tmp_path)
    assert again.stdout.strip() == ANSWER and again.stderr == ""  # compiled and cached afresh


def _old(path: Path, days: float) -> None:
    t = time.time() - days * 86400
    os.utime(path, (t, t), follow_symlinks=False)


def test_pruning_removes_only_its_own_old_folders_and_follows_no_link(tmp_path):
    """Issue 45, item 3: a cache folder that was a link got its target's old files deleted at `import racerlab`."""
    from racerlab import kernelcache

    parent = tmp_path / "numba"
    parent.mkdir()
    target = tmp_path / "someone's"
    target.mkdir()
    (target / "keep.txt").write_text("x")
    _old(target / "keep.txt", 40)
    names = {"current": "aaaaaaaaaaaaaaaa", "old": "bbbbbbbbbbbbbbbb", "recent": "cccccccccccccccc"}
    for name, days in ((names["current"], 40), (names["old"], 15), (names["recent"], 2), ("notes", 40)):
        (parent / name).mkdir()
        (parent / name / "k.nbi").write_text("x")
        _old(parent / name, days)
    (parent / "dddddddddddddddd").symlink_to(target)  # named like one of its own, but a link
    _old(parent / "dddddddddddddddd", 40)
    (parent / "eeeeeeeeeeeeeeee").write_text("a file")
    _old(parent / "eeeeeeeeeeeeeeee", 40)
    assert kernelcache.prune(str(parent), names["current"]) == [names["old"]]
    assert sorted(p.name for p in parent.iterdir()) == sorted(
        [names["current"], names["recent"], "notes", "dddddddddddddddd", "eeeeeeeeeeeeeeee"])
    assert (target / "keep.txt").is_file()
    linked = tmp_path / "linked"
    linked.symlink_to(target)
    (target / "ffffffffffffffff").mkdir()
    _old(target / "ffffffffffffffff", 40)
    assert kernelcache.prune(str(linked), names["current"]) == [] and (target / "ffffffffffffffff").is_dir()


def test_import_racerlab_leaves_a_linked_cache_folders_target_alone(tmp_path):
    target = tmp_path / "big-disk"
    (target / "0123456789abcdef").mkdir(parents=True)
    (target / "photos").mkdir()
    for p in (target / "0123456789abcdef", target / "photos"):
        _old(p, 40)
    (tmp_path / "cache" / "racerlab").mkdir(parents=True)
    (tmp_path / "cache" / "racerlab" / "numba").symlink_to(target)
    out = _run(tmp_path, "import racerlab")
    assert out.returncode == 0, out.stderr
    assert {"0123456789abcdef", "photos"} <= {p.name for p in target.iterdir()}


def test_a_child_of_the_same_sources_keeps_its_parents_folder_and_one_of_other_sources_does_not(tmp_path):
    """A Ray worker or a command's child inherits NUMBA_CACHE_DIR: with the same compiled sources it keeps the
    parent's kernels (whatever its own home); a racerlab of other sources (a base tree beside a branch) gets its own
    fingerprint's folder, not the parent's kernels."""
    code = "import os, racerlab; print(os.environ['NUMBA_CACHE_DIR'])"
    chosen = _run(tmp_path, code).stdout.strip()
    inherited = {"NUMBA_CACHE_DIR": chosen, "RACERLAB_KERNEL_CACHE": chosen, "XDG_CACHE_HOME": str(tmp_path / "c2")}
    assert _run(tmp_path, code, **inherited).stdout.strip() == chosen
    other = _copy(tmp_path)
    with open(other / "sim" / "car.py", "a") as fh:
        fh.write("# another version of the car\n")
    got = _run(tmp_path, code, package=other, **inherited).stdout.strip()
    assert got != chosen and Path(got).is_relative_to(tmp_path / "c2")
