"""The dependency rule: who may import whom inside racerlab.

The allowed table lives in one place, docs/architecture.md ("Who may import whom"); this test
reads it, reads every import in src/racerlab (module level and inside functions alike) and fails
on an import the table does not allow, on a package the table does not list, and on any import
of another package's private module (a name starting with `_`).
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


def imports_of(path: Path, src: Path) -> list[tuple[int, str]]:
    """(line, absolute dotted name) of every racerlab import in a file, relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = _module_name(path, src)
    package = here if path.name == "__init__.py" else here[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod == "racerlab":  # `from racerlab import sim` names the part
                found += [(node.lineno, f"racerlab.{a.name}") for a in node.names]
                continue
            found.append((node.lineno, mod))
            # `from racerlab.sim import _kernels` names a module too
            found += [(node.lineno, f"{mod}.{a.name}") for a in node.names
                      if a.name.startswith("_") and not a.name.startswith("__")]
    return [(ln, m) for ln, m in found if m == "racerlab" or m.startswith("racerlab.")]


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
            private = [p for p in parts[2:] if p.startswith("_") and not p.startswith("__")]
            if target != unit and private:
                problems.append(f"{where}: {unit} imports {name}, a private module of {target}")
    return problems


def test_every_import_follows_the_table():
    table = read_table(DOC.read_text(encoding="utf-8"))
    problems = violations(SRC, table)
    assert not problems, "import rule broken (docs/architecture.md):\n" + "\n".join(problems)


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
    assert any("a private module of track" in p for p in problems)
    assert any(p.startswith("extra: not in the table") for p in problems)


def test_allowed_imports_pass(tmp_path):
    src = _tree(tmp_path, {"__init__.py": "", "errors.py": "", "track/__init__.py": "from .core import x\n",
                           "track/core.py": "from racerlab.errors import E\nx = 1\n", "sim/__init__.py": "",
                           "sim/core.py": "from racerlab.track import core\nfrom . import _private\n",
                           "sim/_private.py": ""})
    assert violations(src, read_table(TABLE)) == []
