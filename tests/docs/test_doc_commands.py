"""Every ```bash block of README.md and docs/**/*.md runs as written (tests/docs/doc_blocks.py has the rules).

Each markdown page gets a fresh copy of the repository's files a user has (tracked and untracked-but-not-ignored:
what a clone holds, no outputs/), with ../shared beside it as in CI, and its blocks run in order in that copy, as a
user follows the page: `bash -e -o pipefail`, `python` on PATH being this test's interpreter, and the copy's
torchrefl imported. Outputs land in the copy, never in the repository. Blocks marked `skip` (or `slow`, unless
TORCHREFL_DOC_TEST_SLOW=1) are reported as skipped with their reason.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from doc_blocks import DocBlock, DocBlockError, doc_files, read_blocks

ROOT = Path(__file__).resolve().parents[2]
RUN_SLOW = os.environ.get("TORCHREFL_DOC_TEST_SLOW") == "1"
BLOCK_TIMEOUT_S = 900
#: ignored by a copy when git cannot list the files (no git on PATH, not a checkout)
NOT_A_USERS = shutil.ignore_patterns(".git", ".venv", "outputs", "__pycache__", "*.egg-info", "build", "dist")


def _blocks() -> list[DocBlock]:
    out = []
    for path in doc_files(ROOT):
        try:
            out.extend(read_blocks(path, ROOT))
        except DocBlockError:
            pass  # test_docs_follow_the_block_rules reports it
    return out


BLOCKS = _blocks()


@dataclass
class Outcome:
    """How one block ran."""

    returncode: int
    output: str


def user_copy(dest: Path) -> Path:
    """A copy of the repository's files a user has, at dest/repo, with ../shared beside it when there is one."""
    repo = dest / "repo"
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=ROOT, capture_output=True
    )
    if listed.returncode == 0:
        for name in filter(None, listed.stdout.decode().split("\0")):
            src = ROOT / name
            if src.is_file():
                (repo / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(src, repo / name)
    else:
        shutil.copytree(ROOT, repo, ignore=NOT_A_USERS)
    shared = ROOT.parent / "shared"
    if shared.is_dir():
        (dest / "shared").symlink_to(shared.resolve(), target_is_directory=True)
    return repo


def user_env(bin_dir: Path, repo: Path) -> dict:
    """The environment a block runs in: `python` is this interpreter, the copy's torchrefl is the one imported."""
    bin_dir.mkdir(parents=True, exist_ok=True)
    wrapper = bin_dir / "python"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n')
    wrapper.chmod(0o755)
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(bin_dir), str(Path(sys.executable).parent), env.get("PATH", "")])
    env["PYTHONPATH"] = str(repo)
    env["MPLBACKEND"] = "Agg"
    return env


def run_block(command: str, cwd: Path, env: dict, timeout_s: float = BLOCK_TIMEOUT_S) -> Outcome:
    """Run one block's text with bash -e -o pipefail in `cwd`."""
    try:
        done = subprocess.run(
            ["bash", "-e", "-o", "pipefail", "-c", command],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
    except subprocess.TimeoutExpired as e:
        return Outcome(124, f"timed out after {timeout_s} s\n{e.stdout or ''}{e.stderr or ''}")
    return Outcome(done.returncode, done.stdout + done.stderr)


def _runs(block: DocBlock) -> bool:
    return block.skip is None or (block.slow and RUN_SLOW)


@dataclass
class PageCopy:
    """A page's copy of the repository: where, its environment, the commands run in it, each block's outcome."""

    repo: Path
    env: dict
    ran: tuple[str, ...] = ()
    done: dict[int, Outcome] = field(default_factory=dict)


def _prefixes(blocks: list[DocBlock]) -> list[tuple[str, ...]]:
    """The command sequences a page runs: after its first block, its first two, ..."""
    commands = tuple(b.command() for b in blocks)
    return [commands[: k + 1] for k in range(len(commands))]


class Pages:
    """One copy of the repository per markdown page; runs a page's blocks in order, each once. A page whose first
    blocks are the very commands another page already ran from a fresh copy (README.md's default run and
    docs/results/default.md's) starts from a snapshot of that copy instead of running them again."""

    def __init__(self, work: Path):
        self.work = work
        self.blocks = {}
        for b in BLOCKS:
            if _runs(b):
                self.blocks.setdefault(b.file, []).append(b)
        seen: dict[tuple[str, ...], int] = {}
        for blocks in self.blocks.values():
            for prefix in _prefixes(blocks):
                seen[prefix] = seen.get(prefix, 0) + 1
        self.shared = {prefix for prefix, n in seen.items() if n > 1}
        self.snapshots: dict[tuple[str, ...], tuple[Path, Outcome]] = {}
        self.pages: dict[Path, PageCopy] = {}

    def _page(self, path: Path) -> PageCopy:
        if path not in self.pages:
            dest = self.work / str(len(self.pages))
            dest.mkdir(parents=True)
            repo = user_copy(dest)
            self.pages[path] = PageCopy(repo, user_env(dest / "bin", repo))
        return self.pages[path]

    def _run(self, page: PageCopy, block: DocBlock) -> Outcome:
        key = page.ran + (block.command(),)
        if key in self.snapshots:
            snapshot, outcome = self.snapshots[key]
            shutil.rmtree(page.repo)
            shutil.copytree(snapshot, page.repo, symlinks=True)
        else:
            outcome = run_block(block.command(), page.repo, page.env)
            if key in self.shared and outcome.returncode == 0:
                snapshot = self.work / "snapshots" / str(len(self.snapshots))
                shutil.copytree(page.repo, snapshot, symlinks=True)
                self.snapshots[key] = (snapshot, outcome)
        page.ran = key
        return outcome

    def run_through(self, block: DocBlock) -> Outcome:
        """Run the page's blocks up to and including `block` (those not run yet); its outcome."""
        page, blocks = self._page(block.file), self.blocks[block.file]
        for b in blocks[: blocks.index(block) + 1]:
            if b.line not in page.done:
                page.done[b.line] = outcome = self._run(page, b)
                if outcome.returncode != 0 and b is not block:
                    return Outcome(outcome.returncode, f"an earlier block failed, {b.where}:\n{outcome.output}")
        return page.done[block.line]


@pytest.fixture(scope="session")
def pages(tmp_path_factory):
    return Pages(tmp_path_factory.mktemp("doc_commands"))


def _missing_data(block: DocBlock) -> str | None:
    """A `replace` target outside the repository (../shared/...) that this machine does not have."""
    for _, new in block.replace:
        if new.startswith("../") and not (ROOT / new).exists():
            return new
    return None


def test_docs_follow_the_block_rules():
    """Every fence has a language, every marker is known, has its reason and stands above a ```bash block."""
    errors = []
    for path in doc_files(ROOT):
        try:
            read_blocks(path, ROOT)
        except DocBlockError as e:
            errors.append(str(e))
    assert not errors, "\n".join(errors)
    assert BLOCKS, "no ```bash block found in README.md and docs/"


@pytest.mark.parametrize("block", BLOCKS, ids=[b.where for b in BLOCKS])
def test_doc_block_runs_as_written(block, pages):
    if not _runs(block):
        kind = "slow (TORCHREFL_DOC_TEST_SLOW=1 runs it)" if block.slow else "skip"
        pytest.skip(f"{block.where} marked {kind}: {block.skip}")
    missing = _missing_data(block)
    if missing:
        pytest.skip(f"{block.where} needs {missing}, not present on this machine")
    outcome = pages.run_through(block)
    assert outcome.returncode == 0, (
        f"{block.where} failed as written (exit {outcome.returncode}):\n"
        f"{block.command()}\n--- output (last 4000 characters) ---\n{outcome.output[-4000:]}"
    )


# ---------------------------------------------------------------------------- the machinery on small pages


def _page(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "page.md"
    path.write_text(text)
    return path


def test_markers_are_read(tmp_path):
    page = _page(
        tmp_path,
        "intro\n\n<!-- doc-test: skip, needs a serial port -->\n```bash\nprobe /dev/ttyUSB0\n```\n\n"
        "```python\nx = 1\n```\n<!-- doc-test: replace /path/to/x -> data/x -->\n\n```bash\nls /path/to/x\n```\n"
        "<!-- doc-test: slow, ten minutes -->\n```bash\nsleep 600\n```\n",
    )
    a, b, c = read_blocks(page)
    assert (a.line, a.skip, a.slow, a.text) == (4, "needs a serial port", False, "probe /dev/ttyUSB0\n")
    assert (b.line, b.skip, b.replace, b.command()) == (13, None, (("/path/to/x", "data/x"),), "ls data/x\n")
    assert (c.skip, c.slow) == ("ten minutes", True)


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("```\npython -m torchrefl.train\n```\n", "page.md:1: fenced block without a language"),
        ("<!-- doc-test: skip -->\n```bash\nls\n```\n", "needs a reason"),
        ("<!-- doc-test: skipp, typo -->\n```bash\nls\n```\n", "unknown doc-test marker 'skipp, typo'"),
        ("<!-- doc-test: skip, x -->\n```python\nx = 1\n```\n", "above a ```python block"),
        ("<!-- doc-test: skip, x -->\ntext\n```bash\nls\n```\n", "not directly above"),
        ("```bash\nls\n", "fence never closed"),
    ],
    ids=["untagged", "no-reason", "misspelt", "above-python", "not-above", "unclosed"],
)
def test_broken_pages_are_refused(tmp_path, text, fragment):
    with pytest.raises(DocBlockError) as e:
        read_blocks(_page(tmp_path, text))
    assert fragment in str(e.value)


def test_a_failing_command_fails_and_outputs_stay_in_the_copy(tmp_path):
    (tmp_path / "repo").mkdir()
    env = user_env(tmp_path / "bin", tmp_path / "repo")
    ok = run_block('python -c "import sys; print(sys.executable)" > out.txt\n', tmp_path / "repo", env)
    assert ok.returncode == 0 and (tmp_path / "repo" / "out.txt").read_text().strip() == sys.executable
    bad = run_block("true\nfalse\necho not reached\n", tmp_path / "repo", env)
    assert bad.returncode == 1 and "not reached" not in bad.output
    piped = run_block("false | cat\n", tmp_path / "repo", env)
    assert piped.returncode == 1
