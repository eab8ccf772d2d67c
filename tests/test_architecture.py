"""The dependency rule: who may import whom inside racerlab.

The allowed table lives in one place, docs/architecture.md ("Who may import whom"); this test
reads it, reads every import in src/racerlab (module level and inside functions alike) and fails
on an import the table does not allow, on a package the table does not list, on any import of
another part's private module or name (one starting with `_`), on another part's private name
reached through an imported name (`Trainer._make_world`, `sim._kernels`), and on an edge the table
allows that no import uses (a stale row hides how the parts really depend on each other).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "racerlab"
DOC = ROOT / "docs" / "architecture.md"
HEADING = "## Who may import whom"


def read_table(text: str) -> dict[str, set[str]]:
    """{unit: allowed units} from the markdown table under HEADING."""
    if HEADING not in text:
        raise AssertionError(f"{DOC}: no '{HEADING}' section")
    table: dict[str, set[str]] = {}
    for line in text.split(HEADING, 1)[1].splitlines():
        if line.startswith("## "):
            break
        m = re.match(r"\|\s*`([\w.]+)`\s*\|([^|]*)\|", line)
        if m:
            table[m.group(1)] = set(re.findall(r"`([\w.]+)`", m.group(2)))
    return table


def units(src: Path) -> list[str]:
    """The top-level parts of the package: subpackages and top-level modules."""
    out = []
    for p in sorted(src.iterdir()):
        if p.is_dir() and (p / "__init__.py").exists():
            out.append(p.name)
        elif p.suffix == ".py" and p.stem not in ("__init__", "__main__"):
            out.append(p.stem)
    return out


def _module_name(path: Path, src: Path) -> list[str]:
    rel = path.relative_to(src.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return parts


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _bindings(tree: ast.AST, path: Path, src: Path):
    """(line, absolute dotted name, local name bound to it or None, whether the name is a module imported as
    such) of every import in a tree, relative imports resolved."""
    here = _module_name(path, src)
    package = here if path.name == "__init__.py" else here[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:  # `import racerlab.sim.core` binds `racerlab` (to the root), `... as c` the module
                yield node.lineno, a.name, a.asname or (a.name if "." not in a.name else None), True
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod != "racerlab":  # `from racerlab import sim` names the part itself
                yield node.lineno, mod, None, True
            for a in node.names:
                yield node.lineno, f"{mod}.{a.name}", a.asname or a.name, False


def imports_of(path: Path, src: Path) -> list[tuple[int, str]]:
    """(line, absolute dotted name) of every racerlab import in a file: the modules, the parts taken from the root
    (`from racerlab import sim`) and the private names taken from a module (`from racerlab.sim import _kernels`)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = [(line, name) for line, name, _, module in _bindings(tree, path, src)
             if module or name.count(".") == 1 or _is_private(name.rsplit(".", 1)[-1])]
    return [(ln, m) for ln, m in found if m == "racerlab" or m.startswith("racerlab.")]


def reached_privates(path: Path, src: Path) -> list[tuple[int, str]]:
    """(line, dotted name) of each private attribute reached through a name imported from racerlab: after
    `from racerlab.train.loop import Trainer`, `Trainer._make_world` reaches racerlab.train.loop.Trainer._make_world."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names = {bound: name for _, name, bound, _ in _bindings(tree, path, src)
             if bound is not None and name.startswith("racerlab.")}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _is_private(node.attr):
            chain, base = [node.attr], node.value
            while isinstance(base, ast.Attribute):
                chain.append(base.attr)
                base = base.value
            if isinstance(base, ast.Name) and base.id in names:
                found.append((node.lineno, ".".join([names[base.id], *reversed(chain)])))
    return found


def _class_privates(src: Path, dotted: str) -> set[str]:
    """Private names a class defines or sets on `self` (`racerlab.train.loop.Trainer` → {"_make_world", ...})."""
    module, _, cls = dotted.rpartition(".")
    base = src.parent.joinpath(*module.split("."))
    path = base / "__init__.py" if base.is_dir() else base.with_suffix(".py")
    if not path.is_file():
        return set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ClassDef) and node.name == cls:
            own = {n.name for n in node.body if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)}
            own |= {a.attr for a in ast.walk(node) if isinstance(a, ast.Attribute) and isinstance(a.value, ast.Name)
                    and a.value.id == "self"}
            return {n for n in own if _is_private(n)}
    return set()


def inherited_privates(path: Path, src: Path) -> list[tuple[int, str]]:
    """(line, dotted name) of each private name of a base class from racerlab that a subclass overrides or uses
    through `self` or `super()`: subclassing `Trainer` to replace `_checkpoint_state` is reaching into it."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names = {bound: name for _, name, bound, _ in _bindings(tree, path, src)
             if bound is not None and name.startswith("racerlab.")}
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.ClassDef):
            continue
        for b in node.bases:
            if not (isinstance(b, ast.Name) and b.id in names):
                continue
            privates = _class_privates(src, names[b.id])
            for n in ast.walk(node):
                if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef) and n.name in privates:
                    found.append((n.lineno, f"{names[b.id]}.{n.name}"))
                elif isinstance(n, ast.Attribute) and n.attr in privates and (
                        isinstance(n.value, ast.Name) and n.value.id == "self"
                        or isinstance(n.value, ast.Call) and getattr(n.value.func, "id", "") == "super"):
                    found.append((n.lineno, f"{names[b.id]}.{n.attr}"))
    return sorted(set(found))


def violations(src: Path, table: dict[str, set[str]]) -> list[str]:
    problems = []
    for unit in units(src):
        if unit not in table:
            problems.append(f"{unit}: not in the table of {DOC.name}; add a row saying what it may import")
    for path in sorted(src.rglob("*.py")):
        mine = _module_name(path, src)
        unit = mine[1] if len(mine) > 1 else "__init__"
        if unit in ("__init__", "__main__"):
            continue  # the package root re-exports and the entry point calls the CLI
        allowed = table.get(unit, set()) | {unit}
        for line, name in imports_of(path, src):
            parts = name.split(".")
            if len(parts) < 2:
                problems.append(f"{path.relative_to(src.parent)}:{line}: imports the racerlab root; import a part")
                continue
            target = parts[1]
            if target.startswith("__"):
                continue  # the root's own metadata, such as racerlab.__version__
            where = f"{path.relative_to(src.parent)}:{line}"
            if target != unit and target not in allowed:
                problems.append(f"{where}: {unit} imports {name}, but {unit} may import only {sorted(allowed)}")
            private = [p for p in parts[2:] if _is_private(p)]
            if target != unit and private:
                problems.append(f"{where}: {unit} imports {name}, a private name of {target}")
        for line, name in reached_privates(path, src) + inherited_privates(path, src):
            target = name.split(".")[1]
            if target != unit:
                problems.append(f"{path.relative_to(src.parent)}:{line}: {unit} reaches {name}, a private name of "
                                f"{target}; give {target} a public way to do it")
    return problems


def used_edges(src: Path) -> set[tuple[str, str]]:
    """(part, part it imports) of every import between two parts."""
    edges = set()
    for path in sorted(src.rglob("*.py")):
        mine = _module_name(path, src)
        unit = mine[1] if len(mine) > 1 else "__init__"
        for _, name in imports_of(path, src):
            parts = name.split(".")
            if len(parts) > 1 and not parts[1].startswith("__") and parts[1] != unit:
                edges.add((unit, parts[1]))
    return edges


def unused_edges(src: Path, table: dict[str, set[str]]) -> list[str]:
    used = used_edges(src)
    return [f"{unit} → {target}" for unit in table for target in sorted(table[unit]) if (unit, target) not in used]


def test_every_import_follows_the_table():
    table = read_table(DOC.read_text(encoding="utf-8"))
    problems = violations(SRC, table)
    assert not problems, "import rule broken (docs/architecture.md):\n" + "\n".join(problems)


def test_every_edge_of_the_table_is_used():
    table = read_table(DOC.read_text(encoding="utf-8"))
    stale = unused_edges(SRC, table)
    assert not stale, ("docs/architecture.md allows imports that no module makes; remove them from the table "
                       "(or the code that used them went elsewhere): " + ", ".join(stale))


def test_table_names_only_real_parts():
    table = read_table(DOC.read_text(encoding="utf-8"))
    real = set(units(SRC))
    stale = {u for u in table if u not in real} | {a for v in table.values() for a in v if a not in real}
    assert not stale, f"docs/architecture.md names parts that do not exist: {sorted(stale)}"


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    src = tmp_path / "racerlab"
    for rel, text in files.items():
        p = src / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return src


TABLE = """
## Who may import whom

| part | may import |
|---|---|
| `track` | `errors` |
| `sim` | `errors`, `track` |
| `errors` | — |
"""


@pytest.mark.parametrize("source, complaint", [
    ("from racerlab.sim import core\n", "track imports racerlab.sim"),
    ("def f():\n    from ..sim import core\n", "track imports racerlab.sim"),
    ("import racerlab.sim.core\n", "track imports racerlab.sim.core"),
])
def test_an_import_against_the_table_fails(tmp_path, source, complaint):
    src = _tree(tmp_path, {"__init__.py": "", "errors.py": "", "track/__init__.py": "", "track/core.py": source,
                           "sim/__init__.py": "", "sim/core.py": "from racerlab.track import core\n"})
    problems = violations(src, read_table(TABLE))
    assert len(problems) == 1 and complaint in problems[0] and "track/core.py" in problems[0]


def test_private_modules_and_unlisted_parts_fail(tmp_path):
    src = _tree(tmp_path, {"__init__.py": "", "errors.py": "", "track/__init__.py": "", "track/_k.py": "",
                           "sim/__init__.py": "", "sim/core.py": "from racerlab.track import _k\n",
                           "extra/__init__.py": "from racerlab import errors\n"})
    problems = violations(src, read_table(TABLE))
    assert any("racerlab.track._k, a private name of track" in p for p in problems)
    assert any(p.startswith("extra: not in the table") for p in problems)


@pytest.mark.parametrize("source, reached", [
    # the cluster's worker borrowed the trainer's world builders this way (issue 26)
    ("from racerlab.track.core import Track\n\nclass W:\n    load = Track._load\n", "racerlab.track.core.Track._load"),
    ("from racerlab.track.core import _helper\n", "racerlab.track.core._helper"),
    ("import racerlab.track.core as tc\n\nx = tc.Track._cache\n", "racerlab.track.core.Track._cache"),
    ("from racerlab import track\n\ndef f():\n    return track.core._grid\n", "racerlab.track.core._grid"),
])
def test_a_private_name_reached_across_parts_fails(tmp_path, source, reached):
    src = _tree(tmp_path, {"__init__.py": "", "errors.py": "", "track/__init__.py": "", "track/core.py": "",
                           "sim/__init__.py": "", "sim/core.py": source})
    problems = violations(src, read_table(TABLE))
    assert len(problems) == 1 and reached in problems[0] and "a private name of track" in problems[0], problems
    assert problems[0].startswith("racerlab/sim/core.py:")


def test_a_subclass_that_overrides_or_uses_a_private_of_another_part_fails(tmp_path):
    # the cluster's trainer replaced four private hooks of `Trainer` and called its logs' `_simtrace` (issue 26)
    base = "class Track:\n    def _cache(self):\n        self._grid = 1\n\n    def public(self):\n        pass\n"
    sub = ("from racerlab.track.core import Track\n\nclass Mine(Track):\n    def _cache(self):\n"
           "        return super()._cache()\n\n    def mine(self):\n        return self._grid, self._own\n\n"
           "    def public(self):\n        self._own = 1\n")
    src = _tree(tmp_path, {"__init__.py": "", "errors.py": "", "track/__init__.py": "", "track/core.py": base,
                           "sim/__init__.py": "", "sim/core.py": sub})
    problems = violations(src, read_table(TABLE))
    assert [p.split(": ")[0] for p in problems] == ["racerlab/sim/core.py:4", "racerlab/sim/core.py:5",
                                                    "racerlab/sim/core.py:8"]
    assert all("a private name of track" in p for p in problems)
    assert "Track._cache" in problems[0] and "Track._grid" in problems[2]


def test_a_part_may_reach_its_own_private_names(tmp_path):
    src = _tree(tmp_path, {"__init__.py": "", "errors.py": "", "track/__init__.py": "",
                           "track/core.py": "class Track:\n    _n = 1\n",
                           "track/grid.py": "from racerlab.track.core import Track\n\nx = Track._n\n",
                           "sim/__init__.py": "",
                           "sim/core.py": "from racerlab.track.core import Track\n\nx = Track.n\n"})
    assert violations(src, read_table(TABLE)) == []


def test_an_allowed_edge_no_import_uses_is_listed(tmp_path):
    src = _tree(tmp_path, {"__init__.py": "", "errors.py": "", "track/__init__.py": "from racerlab import errors\n",
                           "sim/__init__.py": "from racerlab.track import x\n"})
    assert unused_edges(src, read_table(TABLE)) == ["sim → errors"]


def test_allowed_imports_pass(tmp_path):
    src = _tree(tmp_path, {"__init__.py": "", "errors.py": "", "track/__init__.py": "from .core import x\n",
                           "track/core.py": "from racerlab.errors import E\nx = 1\n", "sim/__init__.py": "",
                           "sim/core.py": "from racerlab.track import core\nfrom . import _private\n",
                           "sim/_private.py": ""})
    assert violations(src, read_table(TABLE)) == []


BUILDERS = {"Simulator", "Camera", "Lidar", "CameraObservation", "LidarObservation", "CombinedObservation",
            "build_observation", "make_observation", "place_cars", "ObjectSet"}
MAY_BUILD = ("sim", "train/worlds.py")  # the simulator's own part, and the worlds of a run for anyone who trains


def _called_names(path: Path) -> list[tuple[int, str]]:
    """(line, name) of every call in a file to a bare name or an attribute (`Simulator(...)`, `core.Simulator(...)`)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
            if name:
                out.append((node.lineno, name))
    return out


def builds_outside(src: Path) -> list[str]:
    """Calls that build a simulator or a sensor outside `sim` and `train.worlds`."""
    found = []
    for path in sorted(src.rglob("*.py")):
        rel = path.relative_to(src).as_posix()
        if rel.startswith(MAY_BUILD[0] + "/") or rel == MAY_BUILD[1]:
            continue
        found += [f"{rel}:{line}: builds {name}" for line, name in _called_names(path) if name in BUILDERS]
    return found


def test_only_sim_and_train_worlds_build_simulators_and_sensors():
    found = builds_outside(SRC)
    assert not found, ("a part builds its own simulator or sensor; drive a sim.World built by train.worlds "
                       "(WorldBuilder) instead:\n" + "\n".join(found))


def test_the_consoles_live_frames_come_from_a_world():
    calls = {name for _, name in _called_names(SRC / "console" / "live.py")}
    assert "WorldBuilder" in calls and not calls & BUILDERS


def test_a_part_that_builds_its_own_sensor_is_named(tmp_path):
    src = _tree(tmp_path, {"__init__.py": "", "console/live.py": "from x import Camera\n\nc = Camera(sim)\n",
                           "sim/core.py": "s = Simulator(t, 1)\n", "train/worlds.py": "s = Simulator(t, 1)\n",
                           "train/loop.py": "import racerlab.sim.core as c\n\ns = c.Simulator(t, 1)\n"})
    assert builds_outside(src) == ["console/live.py:3: builds Camera", "train/loop.py:3: builds Simulator"]
