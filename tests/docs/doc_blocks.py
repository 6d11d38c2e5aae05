"""The command blocks of the user docs (README.md, docs/**/*.md) and their doc-test markers.

Every fenced block names its language (```bash, ```python, ```text, ```yaml ...): an untagged fence is a
DocBlockError, so no command hides from the test in a block it does not read. A ```bash block is run as written
(tests/docs/test_doc_commands.py) unless HTML comments on the lines right above its fence say otherwise:

    <!-- doc-test: skip, REASON -->         never run (pip installs, real serial hardware); listed with REASON
    <!-- doc-test: slow, REASON -->         run only with TORCHREFL_DOC_TEST_SLOW=1 (runs of many minutes)
    <!-- doc-test: replace OLD -> NEW -->   run with OLD (a placeholder such as /path/to/scan) replaced by NEW,
                                            e.g. a path relative to the repository root that the test has

A marker that is misspelt, has no reason, or stands above no ```bash block is a DocBlockError too.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

FENCE = re.compile(r"^\s*(`{3,})(.*)$")
MARKER = re.compile(r"^\s*<!--\s*doc-test:\s*(.*?)\s*-->\s*$")
RUN_LANGUAGE = "bash"


class DocBlockError(Exception):
    """A fence or doc-test marker of a markdown file breaks the rules above; the message names file and line."""


@dataclass(frozen=True)
class DocBlock:
    """One ```bash block: where it is, its text as a user copies it and what its markers say."""

    file: Path
    name: str  # how messages name the file (its path relative to the repository)
    line: int  # 1-based line of the opening fence
    text: str
    skip: str | None = None  # the reason, for `skip` and `slow` blocks
    slow: bool = False
    replace: tuple[tuple[str, str], ...] = field(default_factory=tuple)

    @property
    def where(self) -> str:
        return f"{self.name}:{self.line}"

    def command(self) -> str:
        """The text the test runs: the user's text with each `replace` marker applied."""
        text = self.text
        for old, new in self.replace:
            if old not in text:
                raise DocBlockError(f"{self.where}: replace marker names '{old}', which the block does not contain")
            text = text.replace(old, new)
        return text


def _parse_marker(body: str, where: str) -> dict:
    """One marker's effect as DocBlock keyword arguments."""
    verb = re.match(r"^(skip|slow)\s*(?:,\s*(.*))?$", body)
    if verb:
        if not verb.group(2):
            raise DocBlockError(
                f"{where}: doc-test marker '{body}' needs a reason: <!-- doc-test: {verb.group(1)}, REASON -->"
            )
        return {"skip": verb.group(2), "slow": verb.group(1) == "slow"}
    replace = re.match(r"^replace\s+(\S.*?)\s+->\s+(\S.*)$", body)
    if replace:
        return {"replace": ((replace.group(1), replace.group(2)),)}
    raise DocBlockError(
        f"{where}: unknown doc-test marker '{body}' (expected 'skip, REASON', 'slow, REASON' or 'replace OLD -> NEW')"
    )


def _merge(markers: list[dict]) -> dict:
    out: dict = {}
    for m in markers:
        out["replace"] = out.get("replace", ()) + m.pop("replace", ())
        out.update(m)
    return out


def read_blocks(path: Path, root: Path | None = None) -> list[DocBlock]:
    """The ```bash blocks of one markdown file, in order, with their markers (DocBlockError on a broken rule).
    Messages name the file relative to `root` when given."""
    name = str(path.relative_to(root)) if root else path.name
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks, pending, i = [], [], 0
    while i < len(lines):
        where = f"{name}:{i + 1}"
        marker, fence = MARKER.match(lines[i]), FENCE.match(lines[i])
        if marker:
            pending.append(_parse_marker(marker.group(1), where))
            i += 1
            continue
        if fence:
            ticks, language = fence.group(1), fence.group(2).strip()
            end = next((j for j in range(i + 1, len(lines)) if lines[j].strip() == ticks), None)
            if end is None:
                raise DocBlockError(f"{where}: fence never closed")
            if not language:
                raise DocBlockError(
                    f"{where}: fenced block without a language; tag it ```bash (a command a user runs: the test runs "
                    "it), ```text, ```yaml or ```python"
                )
            if language == RUN_LANGUAGE:
                indent = len(lines[i]) - len(lines[i].lstrip())
                text = "\n".join(line[indent:] for line in lines[i + 1 : end]) + "\n"
                blocks.append(DocBlock(path, name, i + 1, text, **_merge(pending)))
            elif pending:
                raise DocBlockError(f"{where}: doc-test marker above a ```{language} block (only ```bash blocks run)")
            pending, i = [], end + 1
            continue
        if pending and lines[i].strip():
            raise DocBlockError(f"{name}:{i}: doc-test marker not directly above a ```bash fence")
        i += 1
    if pending:
        raise DocBlockError(f"{name}: doc-test marker at the end of the file, above no block")
    return blocks


def doc_files(root: Path) -> list[Path]:
    """README.md and every markdown page under docs/, sorted."""
    return [root / "README.md", *sorted((root / "docs").rglob("*.md"))]
