"""The batch summary: one row per capture in `<output>/summary.json` and `summary.csv`, rewritten (atomically) as
each fit finishes."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from torchrefl.core.atomic_files import atomic_write_text

JSON, CSV = "summary.json", "summary.csv"
#: the row's status: complete (fitted now), skipped (an earlier run completed it), failed, pending (not finished yet)
STATUSES = ("complete", "skipped", "failed", "pending")


@dataclass
class Row:
    """One capture's line of the summary; the metrics are None where the run has none (no held-out light, no truth)."""

    name: str
    status: str
    output: str
    error: str = ""
    model: str | None = None
    seconds: float | None = None
    cpu_seconds: float | None = None  # CPU time of the fit's process (all its threads): > seconds means threads ran
    attempts: int = 0
    holdout_mean_abs_diff_8bit: float | None = None
    holdout_rmse_8bit: float | None = None
    pd_rmse: float | None = None
    ps_rmse: float | None = None
    sigma_rmse: float | None = None

    @property
    def done(self) -> bool:
        return self.status in ("complete", "skipped")


def row_of(
    name: str,
    status: str,
    output: Path,
    metrics: dict,
    seconds: float | None,
    attempts: int = 1,
    cpu: float | None = None,
) -> Row:
    """The row of a finished run from its metrics (metrics.json's keys), its wall and CPU seconds."""
    holdout, truth = metrics.get("holdout") or {}, metrics.get("ground_truth") or {}
    return Row(
        name,
        status,
        str(output),
        model=metrics.get("model"),
        seconds=None if seconds is None else round(seconds, 2),
        cpu_seconds=None if cpu is None else round(cpu, 2),
        attempts=attempts,
        holdout_mean_abs_diff_8bit=holdout.get("mean_abs_diff_8bit"),
        holdout_rmse_8bit=holdout.get("rmse_8bit"),
        pd_rmse=truth.get("pd_rmse"),
        ps_rmse=truth.get("ps_rmse"),
        sigma_rmse=truth.get("sigma_rmse"),
    )


def write_summary(output: Path, rows: list[Row]) -> None:
    """Rewrite summary.json (a list of rows) and summary.csv in `output`, each file whole or not at all."""
    output.mkdir(parents=True, exist_ok=True)
    docs = [asdict(r) for r in rows]
    atomic_write_text(output / JSON, json.dumps(docs, indent=1))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=[f.name for f in fields(Row)], lineterminator="\n")
    writer.writeheader()
    writer.writerows(docs)
    atomic_write_text(output / CSV, buf.getvalue())


def read_summary(output: Path) -> list[Row]:
    """The rows of `output`/summary.json."""
    return [Row(**doc) for doc in json.loads((Path(output) / JSON).read_text())]


def last_line(rows: list[Row]) -> str:
    """The command's last line: how many failed, else that all completed."""
    failed = sum(r.status == "failed" for r in rows)
    skipped = sum(r.status == "skipped" for r in rows)
    if failed:
        return f"{failed} of {len(rows)} captures failed (summary.csv has each one's error)"
    return f"all {len(rows)} captures complete ({skipped} already complete, skipped)"
