"""The capture folder the rig writes (the cylindrical_scan contract): textures/NNN.png and
manifest.jsonl, kept consistent across crashes.

An image is written to textures/.tmp-NNN.png, fsynced, renamed to textures/NNN.png (the directory
fsynced), and only then is its manifest line appended and fsynced. So at any instant the folder is
either consistent or holds extra files that `recover` removes: temp files, an image whose line was
never written, a torn last manifest line.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import yaml

from torchrefl.core.atomic_files import atomic_write_text, fsync_dir
from torchrefl.errors import CaptureError

MANIFEST = "manifest.jsonl"
TEXTURES = "textures"
TEMP_PREFIX = ".tmp-"
IMAGE_RE = re.compile(r"^\d{3,}\.png$")


class CaptureFolder:
    """folder/manifest.jsonl + folder/textures/; entries: the manifest's dicts in file order."""

    def __init__(self, root):
        self.root = Path(root)
        self.textures = self.root / TEXTURES
        self.manifest = self.root / MANIFEST
        self.entries: list[dict] = []

    def recover(self) -> dict:
        """Make the folder consistent and load the manifest. Drops a torn (unparsable) last line,
        drops entries whose image is missing, deletes temp files and images without an entry.
        Returns counts of what was removed."""
        self.textures.mkdir(parents=True, exist_ok=True)
        report = {"torn_lines": 0, "entries_without_image": 0, "temp_files": 0, "orphan_images": 0}
        entries, rewrite = [], False
        if self.manifest.exists():
            raw = self.manifest.read_bytes()
            lines = raw.split(b"\n")
            for k, line in enumerate(lines):
                if not line.strip():
                    continue
                last = k == len(lines) - 1 or all(not x.strip() for x in lines[k + 1 :])
                try:
                    entry = json.loads(line.decode("utf-8"))
                    if not isinstance(entry, dict) or "image" not in entry or "index" not in entry:
                        raise ValueError("not a manifest entry")
                except (ValueError, UnicodeDecodeError):
                    if last:  # a write cut short by a crash: the image will be re-shot
                        report["torn_lines"] += 1
                        rewrite = True
                        continue
                    raise CaptureError(
                        f"{self.manifest}: line {k + 1} is not a valid manifest entry "
                        f"({line[:80]!r}); fix or remove it by hand"
                    ) from None
                if not (self.root / entry["image"]).is_file():
                    report["entries_without_image"] += 1
                    rewrite = True
                    continue
                entries.append(entry)
            if raw and not raw.endswith(b"\n"):
                rewrite = True
        indices = [e["index"] for e in entries]
        if len(set(indices)) != len(indices):
            raise CaptureError(
                f"{self.manifest}: repeated indices {sorted(i for i in set(indices) if indices.count(i) > 1)}"
            )
        if rewrite:
            atomic_write_text(self.manifest, "".join(json.dumps(e) + "\n" for e in entries))
        listed = {Path(e["image"]).name for e in entries}
        for p in sorted(self.textures.iterdir()):
            if p.name.startswith(TEMP_PREFIX):
                p.unlink()
                report["temp_files"] += 1
            elif IMAGE_RE.match(p.name) and p.name not in listed:
                p.unlink()
                report["orphan_images"] += 1
        self.entries = entries
        return report

    def next_index(self) -> int:
        return max((int(e["index"]) for e in self.entries), default=-1) + 1

    def image_name(self, index: int) -> str:
        return f"{TEXTURES}/{index:03d}.png"

    def temp_path(self, index: int) -> Path:
        return self.textures / f"{TEMP_PREFIX}{index:03d}.png"

    def discard(self, path: Path) -> None:
        try:
            Path(path).unlink()
        except FileNotFoundError:
            pass

    def commit(self, temp: Path, entry: dict) -> None:
        """fsync temp, rename it to entry['image'], fsync the directory, then append the manifest line."""
        temp = Path(temp)
        if not temp.is_file() or temp.stat().st_size == 0:
            raise CaptureError(f"{temp}: the camera wrote no image")
        with open(temp, "rb") as f:
            os.fsync(f.fileno())
        final = self.root / entry["image"]
        os.replace(temp, final)
        fsync_dir(self.textures)
        with open(self.manifest, "a") as f:
            f.write(json.dumps(entry) + "\n")
            f.flush()
            os.fsync(f.fileno())
        fsync_dir(self.root)
        self.entries.append(entry)

    def link_scan_yaml(self) -> bool:
        """Point scan.yaml's light list at the manifest (`lights: manifest.jsonl`) when scan.yaml
        exists; returns whether it exists (the scanner writes scan.yaml and range.npy)."""
        path = self.root / "scan.yaml"
        if not path.is_file():
            return False
        try:
            doc = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise CaptureError(f"{path}: not valid YAML: {exc}") from None
        if not isinstance(doc, dict):
            raise CaptureError(f"{path}: expected a mapping at the top level")
        if doc.get("lights") != MANIFEST:
            if doc.get("lights"):
                raise CaptureError(
                    f"{path}: key 'lights' already lists lights inline; the rig records its images "
                    f"in {MANIFEST} (use a fresh folder or remove the inline list)"
                )
            doc["lights"] = MANIFEST
            atomic_write_text(path, yaml.safe_dump(doc, sort_keys=False))
        return True
