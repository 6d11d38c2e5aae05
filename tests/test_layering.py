"""Packages import only downward: each torchrefl package may import only the packages below it."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torchrefl"

#: lowest first; a module may import its own package and any package listed before it
LAYERS = [
    "errors",
    "version",
    "config_loading",
    "config_bundle",
    "config",
    "core",
    "geometry",
    "capture",
    "planning",
    "synthetic",
    "transport",
    "fit",
    "report",
    "rig",
    "run",
    "plan",
    "render",
    "train",
    "batch",
    "cli",
    "__init__",
]


def imported_packages(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "torchrefl":
            names = [node.module] if node.module != "torchrefl" else [f"torchrefl.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names if a.name.split(".")[0] == "torchrefl"]
        out.update(n.split(".")[1] if "." in n else "__init__" for n in names)
    return out


def test_every_import_runs_downward():
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("").parts
        own = rel[0]
        assert own in LAYERS, f"{path}: package '{own}' has no place in LAYERS"
        for target in imported_packages(path) - {own}:
            if LAYERS.index(target) > LAYERS.index(own):
                wrong.append(f"{path.relative_to(PACKAGE.parent)} imports torchrefl.{target}")
    assert not wrong, "imports that run upward:\n" + "\n".join(wrong)


def test_the_check_sees_an_upward_import(tmp_path):
    bad = tmp_path / "m.py"
    bad.write_text("from torchrefl.fit.pipeline import fit_capture\nimport torchrefl.core.rays\n")
    assert imported_packages(bad) == {"fit", "core"}
