"""Installed as a wheel, outside the repository: build the wheel, install it into a fresh virtual environment and
run the bundled default config from an empty folder with the `torchrefl` console command.

The fresh environment gets torchrefl from the wheel only; its dependencies (torch, embreex, ...) are the running
interpreter's, reached through a .pth file instead of being installed again (a path a .pth file adds does not run
that folder's own .pth files, so the editable install of the repository stays out). The run is the default
config at an eighth of its resolution (64 x 57 texels: synthetic.columns / rows / angle_step_deg /
height_step_mm; the same object and lights) with one sub-sample per texel and 3 refinement iterations, to keep the
test short (what it checks is that the installed command runs the bundled config and writes its outputs).
"""

import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: what the wheel is built from: the files an sdist would carry
SOURCES = ("pyproject.toml", "setup.py", "README.md", "torchrefl", "configs")
SMALL = [
    "synthetic.columns=64",
    "synthetic.rows=57",
    "synthetic.angle_step_deg=5.6",
    "synthetic.height_step_mm=4.48",
    "synthetic.supersample=1",
    "fit.iterations=3",
    "output.progress=false",
]


def _run(cmd, **kwargs) -> subprocess.CompletedProcess:
    done = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kwargs)
    assert done.returncode == 0, f"{cmd} exited {done.returncode}\nstdout:\n{done.stdout}\nstderr:\n{done.stderr}"
    return done


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(venv python, venv bin folder, environment) with torchrefl installed from a freshly built wheel."""
    tmp = tmp_path_factory.mktemp("install")
    src = tmp / "src"
    src.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(ROOT / name, src / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    _run([*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", tmp / "dist", src])
    (wheel,) = (tmp / "dist").glob("torchrefl-*.whl")
    _run([sys.executable, "-m", "venv", "--without-pip", tmp / "venv"])
    bin_dir = tmp / "venv" / ("Scripts" if os.name == "nt" else "bin")
    python = bin_dir / ("python.exe" if os.name == "nt" else "python")
    _run([*pip, "--python", python, "install", "--no-deps", "--no-index", wheel])
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    ours = sysconfig.get_paths()
    (site / "torchrefl_test_deps.pth").write_text("\n".join(dict.fromkeys([ours["purelib"], ours["platlib"]])) + "\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    return python, bin_dir, env, site


def test_torchrefl_comes_from_the_wheel(installed, tmp_path):
    python, _, env, site = installed
    code = "import torchrefl, torchrefl.config_bundle as b; print(torchrefl.__file__); print(b.bundled_folder())"
    module, bundle = _run([python, "-c", code], cwd=tmp_path, env=env).stdout.split()
    assert Path(module) == site / "torchrefl" / "__init__.py"
    assert Path(bundle) == site / "torchrefl" / "configs"
    assert ROOT not in Path(module).parents
    modules = lambda top: sorted(str(p.relative_to(top)) for p in top.rglob("*.py") if "__pycache__" not in p.parts)
    assert modules(site / "torchrefl") == modules(ROOT / "torchrefl")  # every module, namespace packages included
    shipped = sorted(p.name for p in (site / "torchrefl" / "configs").glob("*.yaml"))
    assert shipped == sorted(p.name for p in (ROOT / "configs").glob("*.yaml"))


def test_the_default_config_runs_from_an_empty_folder(installed, tmp_path):
    _, bin_dir, env, _ = installed
    work = tmp_path / "empty"
    work.mkdir()
    done = _run([bin_dir / "torchrefl", "train", "default", *SMALL, "output.dir=out", "--quiet"], cwd=work, env=env)
    out = work / "out"
    assert (out / "run_complete.json").is_file() and (out / "params.npz").is_file(), done.stdout + done.stderr
    assert sorted(p.name for p in work.iterdir()) == ["out"]


def test_the_console_command_lists_its_subcommands(installed, tmp_path):
    _, bin_dir, env, _ = installed
    help_text = _run([bin_dir / "torchrefl", "--help"], cwd=tmp_path, env=env).stdout
    assert all(f"\n  {name} " in help_text for name in ("train", "plan", "rig"))


def _bash_blocks(text: str) -> list[str]:
    return re.findall(r"```bash\n(.*?)```", text, flags=re.S)


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    (test_block,) = [b for b in _bash_blocks(readme) if "pytest" in b]
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    assert test_block.strip() in ci_lines


def test_readme_installs_torch_on_its_own_line_naming_the_build():
    blocks = [b for b in _bash_blocks((ROOT / "README.md").read_text()) if "pip install" in b]
    torch_lines = [line for b in blocks for line in b.splitlines() if "pip install torch" in line]
    assert any("--index-url https://download.pytorch.org/whl/cpu" in line for line in torch_lines)  # the CPU build
    assert all(" -e " not in line for line in torch_lines)  # torch is never installed together with the project
