"""The architecture holds: the import contracts of pyproject.toml (layers, the simulator apart,
no cycles) and no class over ~400 lines, its project bases counted."""

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
MAX_CLASS_LINES = 400


def test_the_import_contracts_are_kept():
    """lint-imports reads every import, those inside functions too: a new cycle or an import up
    the layers fails here."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert exe is not None, "import-linter is a test requirement (pip install -e '.[test]')"
    run = subprocess.run([exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "broken" not in run.stdout.lower().split("contracts:")[-1].replace("0 broken", "")


def class_sizes(paths):
    """{name: lines} of every class in ``paths``, each counted with the project classes it
    inherits from (a mixin's lines are the object's)."""
    classes = {}
    for path in paths:
        tree = ast.parse(Path(path).read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                bases = [b.id if isinstance(b, ast.Name) else b.attr
                         for b in node.bases if isinstance(b, (ast.Name, ast.Attribute))]
                classes[f"{path}:{node.name}"] = (node.name, node.end_lineno - node.lineno + 1,
                                                  bases)
    own = {}
    for key, (name, lines, _) in classes.items():
        own.setdefault(name, lines)

    def total(name, lines, bases, seen=()):
        return lines + sum(total(b, own[b], next(v[2] for v in classes.values() if v[0] == b),
                                 seen + (name,))
                           for b in bases if b in own and b not in seen)

    return {key: total(*v) for key, v in classes.items()}


def test_no_class_is_over_400_lines():
    paths = sorted((ROOT / "mavadrc").rglob("*.py")) + sorted((ROOT / "sim").rglob("*.py"))
    big = {k: n for k, n in class_sizes(paths).items() if n > MAX_CLASS_LINES}
    assert not big, f"split these into objects handed what they use: {big}"


def test_the_class_check_counts_a_mixin_as_part_of_its_object(tmp_path):
    """The check above can fail: two classes of 250 lines, one inheriting the other, are one
    object of 500."""
    body = "".join(f"    x{i} = {i}\n" for i in range(249))
    src = tmp_path / "mixed.py"
    src.write_text(f"class Mixin:\n{body}\n\nclass Flight(Mixin):\n{body}")
    sizes = class_sizes([src])
    assert sizes[f"{src}:Mixin"] == 250
    assert sizes[f"{src}:Flight"] == 500


@pytest.mark.parametrize("layer,upper", [("mavadrc.control", "mavadrc.flight"),
                                         ("mavadrc.mission", "mavadrc.study")])
def test_an_upward_import_would_be_caught(tmp_path, layer, upper):
    """The layers contract is live: a copy of the tree with one module importing up the layers
    breaks it."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    copy = tmp_path / "tree"
    for name in ("mavadrc", "sim"):
        shutil.copytree(ROOT / name, copy / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", copy / "pyproject.toml")
    target = copy / Path(*layer.split(".")) / "__init__.py"
    target.write_text(target.read_text() + f"\nimport {upper}  # noqa\n")
    run = subprocess.run([exe, "--no-cache"], cwd=copy, capture_output=True, text=True,
                         timeout=300, env={"PYTHONPATH": str(copy), "PATH": ""})
    assert run.returncode != 0
    assert f"{layer} is not allowed to import {upper}" in run.stdout
