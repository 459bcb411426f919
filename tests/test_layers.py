"""Imports go one way (docs/architecture.md): a module never imports a layer above its own.

    base (errors, limits, io.files, standards, catalogue, extras, version)  <-  face.mesh  <-  io (mesh, glTF, audio, .fap files)
        <-  deform, render  <-  face  <-  build  <-  rig | drivers  <-  player, perform, autorig
        <-  demo, viewer, batch  <-  cli

``face`` sits above deform and render because a Face is completed by a landmark thin-plate spline
and landmarks are detected on a render; ``drivers`` (curves over time) never import ``rig``.
"""

import ast
from pathlib import Path

import pytest

import faceanim

SRC = Path(faceanim.__file__).parent

# module prefix -> rank; a module may import modules of its own rank or lower
RANKS = [
    ("faceanim.errors", 0), ("faceanim.limits", 0), ("faceanim.io.files", 0), ("faceanim.standards", 0), ("faceanim.catalogue", 0), ("faceanim.version", 0), ("faceanim.extras", 0),
    ("faceanim.face.mesh", 1),
    ("faceanim.face.faps", 2), ("faceanim.io", 2),
    ("faceanim.deform.handles", 5),  # reads a handle file: 2D picks are cast onto the face
    ("faceanim.deform", 3), ("faceanim.render", 3),
    ("faceanim.face", 4), ("faceanim.build", 5),
    ("faceanim.rig", 6),
    ("faceanim.drivers", 6),  # beside rig: neither imports the other (checked below)
    ("faceanim.export", 7), ("faceanim.player", 7), ("faceanim.perform", 7), ("faceanim.autorig", 7), ("faceanim.avatar", 7), ("faceanim.demo", 8),
    ("faceanim.viewer", 8), ("faceanim.batch", 8), ("faceanim.live", 8),
    ("faceanim.cli", 9), ("faceanim.__main__", 10),
]


def rank(module: str) -> tuple[str, int]:
    if module == "faceanim":  # the package's own __init__ (only its version); no catch-all below
        return module, 10
    for prefix, r in RANKS:  # most specific prefixes first
        if module == prefix or module.startswith(prefix + "."):
            return prefix, r
    raise AssertionError(f"{module} has no layer; add it to RANKS")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports(path: Path, module: str):
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("faceanim"):
                yield target, node.lineno
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("faceanim"):
                    yield alias.name, node.lineno


def violations(path: Path, module: str) -> list[str]:
    own_layer, own = rank(module)
    wrong = []
    for target, line in imports(path, module):
        layer, r = rank(target)
        sideways = {own_layer, layer} == {"faceanim.rig", "faceanim.drivers"}
        if r > own or sideways:
            wrong.append(f"{path.name}:{line} {module} imports {target}")
    return wrong


def test_imports_go_one_way():
    wrong = [w for path in sorted(SRC.rglob("*.py")) for w in violations(path, module_name(path))]
    assert not wrong, "imports against the layers:\n" + "\n".join(wrong)


def test_the_layer_check_catches_wrong_imports(tmp_path):
    """The checker itself: upward, sideways (driver -> rig) and relative imports are reported."""
    f = tmp_path / "x.py"
    f.write_text("import numpy\nfrom faceanim.rig.mpeg4 import FapRig\ndef g():\n    from ..cli import main\n")
    assert [w.split(" imports ")[1] for w in violations(f, "faceanim.drivers.x")] == ["faceanim.rig.mpeg4",
                                                                                      "faceanim.cli"]
    f.write_text("from faceanim.face.mesh import Mesh\nfrom faceanim.errors import FaceAnimError\n")
    assert violations(f, "faceanim.deform.x") == []
    assert violations(f, "faceanim.errors") != []  # errors is the bottom: it imports nothing of ours
    with pytest.raises(AssertionError, match="has no layer"):  # a new top-level module must be placed
        rank("faceanim.newthing")
