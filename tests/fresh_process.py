"""Run a test module's function in a new Python process: for measurements (peak resident memory) that the process's
history would skew (the heaps, thread pools and peaks that the tests run before it in a pytest worker leave)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent

_CALL = """
import importlib.util, json, sys
sys.path.insert(0, {tests!r})
spec = importlib.util.spec_from_file_location("fresh_module", {file!r})
module = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = module
spec.loader.exec_module(module)
print(json.dumps(getattr(module, {name!r})(*json.loads(sys.argv[1]))))
"""


def run_fresh(module_file: str, name: str, *args, timeout: float = 600.0):
    """`name(*args)` of the module at module_file, called in a new Python process (the project root as its working
    folder and on its path); its JSON result. args and the result must be JSON values."""
    code = _CALL.format(tests=str(TESTS), file=str(Path(module_file).resolve()), name=name)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run(
        [sys.executable, "-c", code, json.dumps(list(args))],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout,
    )  # fmt: skip
    if done.returncode != 0:
        raise AssertionError(f"{name} in a new process exited {done.returncode}:\n{done.stderr[-4000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])
