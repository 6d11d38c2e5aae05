"""One run of the pipeline for a config: capture -> fit -> outputs, into cfg.output.dir.

The run folder is a transaction (torchrefl.report.run_folder): checked before any work, written in a
staging folder beside it and moved into place whole, with a completeness marker written last. A named error
found before any work (no stage completed, nothing written but config.yaml and log.txt) leaves nothing behind;
a run that fails after doing work keeps its files in NAME.failed. The error itself is not printed here: it
propagates (the command line prints it once), with a note saying where a failed run's files are.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import torch

from torchrefl.capture.base import Capture, loader_for
from torchrefl.config import Config, load_config, resolve_path, run_config_text
from torchrefl.core.atomic_files import atomic_write_text
from torchrefl.core.checkpoints import Checkpoints
from torchrefl.core.memory import reset_peak
from torchrefl.core.progress import Stages
from torchrefl.errors import ConfigError, TorchReflError
from torchrefl.fit.pipeline import fit_capture
from torchrefl.report.outputs import write_outputs
from torchrefl.report.run_folder import StagedRunFolder, output_folder
from torchrefl.report.run_result import RunResult, load_run
from torchrefl.report.run_resume import Resumable, resumable_run
from torchrefl.report.summary import summary_table
from torchrefl.version import __version__

#: capture kinds rendered by torchrefl into the run folder (no loader of their own: they write a folder a loader reads)
SYNTHETIC_KINDS = ("synthetic_cylindrical", "synthetic_mesh_views")


class RunLog:
    """Writes timestamped lines to log.txt and (unless quiet, or echo=False) to stderr."""

    def __init__(self, path: Path, quiet: bool = False, append: bool = False):
        self.path = path
        self.quiet = quiet
        self.start = time.perf_counter()
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(path, "a" if append else "w")

    def __call__(self, msg: str, echo: bool = True) -> None:
        line = f"[{time.perf_counter() - self.start:7.2f}s] {msg}"
        self._fh.write(line + "\n")
        self._fh.flush()
        if echo and not self.quiet:
            print(line, file=sys.stderr)

    def close(self):
        self._fh.close()


def torch_device(cfg: Config) -> torch.device:
    """The device named by cfg.device (auto: CUDA when torch sees one)."""
    if cfg.device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device: 'cuda' requested but torch sees no CUDA device (use cpu or auto)")
    return torch.device(cfg.device)


def _capture(cfg: Config, out: Path, stages: Stages, log) -> tuple[Capture, object]:
    if cfg.capture.kind == "synthetic_cylindrical":
        from torchrefl.synthetic.capture import synthetic_capture

        return synthetic_capture(cfg, out, stages, log)
    if cfg.capture.kind == "synthetic_mesh_views":
        from torchrefl.synthetic.views_capture import synthetic_views_capture

        return synthetic_views_capture(cfg, out, stages, log)
    with stages.stage("capture"):
        return loader_for(cfg.capture.kind).load(resolve_path(cfg, cfg.capture.path), cfg, log), None


def _pipeline(cfg: Config, out: Path, target: Path, stages: Stages, log, checkpoints: Checkpoints) -> dict:
    """Capture, fit and outputs into the staging folder `out`; returns the metrics. The capture and the fit are
    checkpoints (a resumed run takes them from there)."""
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    device = torch_device(cfg)
    log(
        f"torchrefl {__version__}: capture {cfg.capture.kind}, model {cfg.fit.model}, brdf {cfg.reflectance.brdf}, "
        f"{cfg.dtype} on {device}; outputs in {target} (written in {out.name} until complete)"
    )
    cap, selection = checkpoints.point("capture", lambda: _capture(cfg, out, stages, log))
    for warning in cap.warnings:
        log(f"warning: {warning}")
    res = checkpoints.point("fit", lambda: fit_capture(cfg, cap, stages, log, device, checkpoints))
    return write_outputs(cfg, out, cap, res, selection, stages, str(device))


def quiet_config(cfg: Config) -> Config:
    """A copy of `cfg` that shows no progress bars (output.progress false): what a quiet run works with."""
    return dataclasses.replace(cfg, output=dataclasses.replace(cfg.output, progress=False))


def run(cfg: Config, quiet: bool = False, overwrite: bool = False, resume: bool = False) -> dict:
    """Run the pipeline for a loaded config; returns the metrics dict. The output folder is checked first
    (OutputError); an earlier run there is replaced only with overwrite=True, and only when this run completes.
    quiet: no log lines and no progress bars on stderr (log.txt is still written). Log lines go to stderr; the
    summary table only to log.txt (the caller shows it: the command line prints it on stdout). resume: continue
    the newest unfinished run of this config from its checkpoints (torchrefl.report.run_resume; none: start anew).
    """
    target = output_folder(cfg.output.dir)
    if cfg.capture.kind not in SYNTHETIC_KINDS:
        loader_for(cfg.capture.kind)  # an unknown kind is refused before the staging folder is made
    config_text = run_config_text(cfg)
    resumable = resumable_run(target, config_text) if resume else Resumable(None, "")
    staged = StagedRunFolder(target, overwrite, resumable.folder)
    reset_peak()  # metrics.json's peak_memory_mb: this run's, not the process's earlier work
    log = RunLog(staged.path / "log.txt", quiet=quiet, append=resumable.folder is not None)
    stages = Stages(log)
    checkpoints = Checkpoints(staged.path, log)
    try:
        if resumable.note:
            log(resumable.note)
        atomic_write_text(staged.path / "config.yaml", config_text)
        metrics = _pipeline(quiet_config(cfg) if quiet else cfg, staged.path, target, stages, log, checkpoints)
        checkpoints.remove()
        start = time.perf_counter()
        staged.commit()
        log(f"run folder {target} complete: marker written and moved into place in {time.perf_counter() - start:.3f} s")
        log(summary_table(metrics), echo=False)
        return metrics
    except BaseException as exc:
        where = f"stage '{stages.failed}'" if stages.failed else "run setup"
        if isinstance(exc, KeyboardInterrupt):
            log(f"interrupted in {where}", echo=False)
        elif isinstance(exc, TorchReflError):
            log(f"error in {where}: {exc}", echo=False)
        else:
            log(f"crashed in {where}: {type(exc).__name__}: {exc}", echo=False)
        if isinstance(exc, TorchReflError) and not stages.completed and staged.wrote_nothing():
            log.close()
            staged.discard()  # found before any work: nothing to keep, the error says it all
            raise
        kept = staged.abandon()
        note = f"the run stopped in {where}: {target} is unchanged; this run's files and log are in {kept}"
        log(note, echo=False)
        exc.add_note(note)
        raise
    finally:
        log.close()


def fit(
    config: Config | str | Path,
    overrides: list[str] = (),
    *,
    quiet: bool = True,
    overwrite: bool = False,
    resume: bool = False,
) -> RunResult:
    """Fit a config (a Config, or a YAML file or bundled config name with dotted.key=value overrides) and return the
    finished run (resume: continue the newest unfinished run of the config, as run)."""
    cfg = config if isinstance(config, Config) else load_config(config, list(overrides))
    run(cfg, quiet=quiet, overwrite=overwrite, resume=resume)
    return load_run(output_folder(cfg.output.dir))
