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
    "config_fields",
    "config_selection",
    "config",
    "core",
    "geometry",
    "capture",
    "planning",
    "synthetic",
    "transport",
    "fit",
    "report",
    "planning.run_scene",  # the planners of a fitted run (a run folder, its uncertainty): above report
    "planning.views_run_scene",
    "planning.scenes",
    "planning.next_best",
    "planning.next_best_plan",
    "rig",
    "run",
    "rig.__main__",  # the rig's command: its adaptive capture fits runs
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
        out.update(layer(n.split(".")[1:]) if "." in n else "__init__" for n in names)
    return out


def layer(parts) -> str:
    """The LAYERS entry of a module (its path's parts below torchrefl, without .py): 'package.module' where LAYERS
    lists it, else its package."""
    return ".".join(parts[:2]) if ".".join(parts[:2]) in LAYERS else parts[0]


def test_every_import_runs_downward():
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        own = layer(path.relative_to(PACKAGE).with_suffix("").parts)
        assert own in LAYERS, f"{path}: package '{own}' has no place in LAYERS"
        for target in imported_packages(path) - {own}:
            if LAYERS.index(target) > LAYERS.index(own):
                wrong.append(f"{path.relative_to(PACKAGE.parent)} imports torchrefl.{target}")
    assert not wrong, "imports that run upward:\n" + "\n".join(wrong)


def test_the_check_sees_an_upward_import(tmp_path):
    bad = tmp_path / "m.py"
    bad.write_text("from torchrefl.fit.pipeline import fit_capture\nimport torchrefl.core.rays\n")
    assert imported_packages(bad) == {"fit", "core"}


def test_a_module_listed_in_layers_has_its_own_place(tmp_path):
    low = tmp_path / "m.py"
    low.write_text(
        "from torchrefl.planning.next_best import next_best_lights\nimport torchrefl.planning.capture_plan\n"
    )
    assert imported_packages(low) == {"planning.next_best", "planning"}
    assert LAYERS.index("planning.next_best") > LAYERS.index("report") > LAYERS.index("planning")
