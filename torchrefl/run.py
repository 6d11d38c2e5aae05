"""One run of the pipeline for a config: capture -> fit -> outputs, into cfg.output.dir."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch

from torchrefl.version import __version__
from torchrefl.capture.base import loader_for
from torchrefl.config import Config, dump_config, load_config, resolve_path
from torchrefl.core.progress import Stages
from torchrefl.errors import ConfigError
from torchrefl.fit.pipeline import fit_capture
from torchrefl.report.outputs import write_outputs
from torchrefl.report.run_result import RunResult, load_run
from torchrefl.report.summary import summary_table


class RunLog:
    """Writes timestamped lines to log.txt and to stderr."""

    def __init__(self, path: Path, quiet: bool = False):
        self.path = path
        self.quiet = quiet
        self.start = time.perf_counter()
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(path, "w")

    def __call__(self, msg: str) -> None:
        line = f"[{time.perf_counter() - self.start:7.2f}s] {msg}"
        self._fh.write(line + "\n")
        self._fh.flush()
        if not self.quiet:
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


def run(cfg: Config, quiet: bool = False) -> dict:
    """Run the pipeline for a loaded config; returns the metrics dict."""
    out = Path(cfg.output.dir)
    out.mkdir(parents=True, exist_ok=True)
    dump_config(cfg, out / "config.yaml")
    log = RunLog(out / "log.txt", quiet=quiet)
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    device = torch_device(cfg)
    stages = Stages(log)
    try:
        log(f"torchrefl {__version__}: capture {cfg.capture.kind}, model {cfg.fit.model}, brdf {cfg.reflectance.brdf}, "
            f"{cfg.dtype} on {device}; outputs in {out}")
        selection = None
        if cfg.capture.kind == "synthetic_cylindrical":
            from torchrefl.synthetic.capture import synthetic_capture

            cap, selection = synthetic_capture(cfg, out, stages, log)
        else:
            with stages.stage("capture"):
                cap = loader_for(cfg.capture.kind).load(resolve_path(cfg, cfg.capture.path), cfg, log)
        res = fit_capture(cfg, cap, stages, log, device)
        metrics = write_outputs(cfg, out, cap, res, selection, stages, str(device))
        log(summary_table(metrics))
        return metrics
    finally:
        log.close()


def fit(config: Config | str | Path, overrides: list[str] = (), *, quiet: bool = True) -> RunResult:
    """Fit a config (a Config, or a YAML file with dotted.key=value overrides) and return the finished run."""
    cfg = config if isinstance(config, Config) else load_config(config, list(overrides))
    run(cfg, quiet=quiet)
    return load_run(cfg.output.dir)
