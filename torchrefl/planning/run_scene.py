"""What a planner needs from a fitted run: its estimate per texel, its scan's geometry and the observation model of
any light, so that the images of candidate lights can be predicted (planning.next_best).

A run folder (torchrefl.report.run_result.load_run: complete, checked) holds the estimate on its texel grid and the
resolved config.yaml; the scan's geometry is read back from the capture folder it was fitted on (a synthetic run's
own `capture/`, a cylindrical_scan's `capture.path`) with the run's geometry settings, so the texels are the fit's.
A light's predicted observations (`observations`) are the loader's: Embree visibility of the camera and of the light
(cast shadows, capture.cylindrical_scan.observation_geometry), the light table's intensity and the camera's kappa.

The sensor noise is the run's (metrics.json `uncertainty.noise_dn`, what its stds were computed with), else
capture.noise_dn.

Texels the run has no estimate of because no fitted observation reached them (coverage "none"; not those the fit set
aside as untrusted or misfit) are `unobserved`: a candidate light may bring them their first observations, and the
planner predicts them at a stand-in, the median of the estimated texels' parameters, per channel (the object's
typical material), since it knows nothing closer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from torchrefl.capture.cylindrical_rig import light_grid_positions
from torchrefl.capture.cylindrical_scan import CylindricalScanLoader, ScanGeometry, observation_geometry
from torchrefl.capture.scan_yaml import read_scan_yaml
from torchrefl.config import Config, load_config, resolve_path
from torchrefl.core.observations import Observations
from torchrefl.errors import ConfigError, RunFolderError
from torchrefl.fit.initialise import COVER_FULL, COVER_NONE
from torchrefl.fit.pipeline import held_out
from torchrefl.fit.uncertainty import ParameterRanges
from torchrefl.report.run_result import CONFIG, RunResult, load_run

#: the capture kinds whose runs the planner reads (a scan's head-frame light positions)
SCAN_KINDS = ("synthetic_cylindrical", "cylindrical_scan")
#: the saturation level of a scan.yaml that gives none (capture.cylindrical_scan's default)
DEFAULT_SATURATION = 0.995


@dataclass
class RunScene:
    """A fitted scan seen by a planner, over the T texels of its surface.

    run: the RunResult; cfg: its resolved Config; geometry: the scan's ScanGeometry (the fit's texels); pd (T, 3),
    ps (T, C), sigma (T,): the estimate (the fit's dtype; at an unobserved texel the stand-in, module docstring; 0
    at the other texels without one); estimated (T,) bool: texels with an estimate; unobserved (T,) bool: texels
    without one that no fitted observation reached; lobe_measured (T,) bool: Ps, sigma from the texel's own
    observations; n_specular (T,) the fitted strong-specular (T_spec) observations; lights (P, 3) head-frame
    positions [lateral, vertical, radial] mm of the lights the run fitted; intensity (3,) the light table's radiant
    intensity (a candidate's); kappa (3,) the run's; saturation_level: sensor fraction at which an observation is
    saturated; noise_dn (3,) per channel, 8-bit DN; ranges: the uncertainty's broad prior."""

    run: RunResult
    cfg: Config
    geometry: ScanGeometry
    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    estimated: torch.Tensor
    unobserved: torch.Tensor
    lobe_measured: torch.Tensor
    n_specular: torch.Tensor
    lights: np.ndarray
    intensity: np.ndarray
    kappa: np.ndarray
    saturation_level: float
    noise_dn: torch.Tensor
    ranges: ParameterRanges
    #: rows of `observations` per light (a scan has one camera)
    images_per_light = 1

    @property
    def normals(self) -> torch.Tensor:
        """(T, 3) unit texel normals (the estimate's dtype)."""
        return self.geometry.surface.normals.to(self.pd.dtype)

    def default_candidates(self) -> np.ndarray:
        """(M, 3) the config's light grid `selection.grid` (head frame, mm): the candidates the run was chosen from."""
        g = self.cfg.selection.grid
        return light_grid_positions(
            g.columns, g.rows, g.spacing_mm, g.radial_mm, g.center_lateral_mm, g.center_vertical_mm
        )

    def observations(self, positions: np.ndarray) -> Observations:
        """The geometry of M lights at head-frame positions (M, 3) mm over the texels as the loader computes it
        (intensity 0: nothing measured); valid: the camera sees the texel, the light is in front and not blocked."""
        g = self.cfg.geometry
        og = observation_geometry(self.geometry, positions, shadow_offset=g.shadow_offset_mm)
        M = len(positions)
        dtype = self.pd.dtype
        t = lambda a: torch.from_numpy(np.array(a)).to(dtype)
        return Observations(
            intensity=torch.zeros(M, len(og["view_dir"]), 3, dtype=dtype),
            valid=torch.from_numpy(og["seen"][None] & og["lit"] & ~og["shadowed"]),
            saturated=torch.zeros(og["shadowed"].shape, dtype=torch.bool),
            shadowed=torch.from_numpy(og["shadowed"]),
            light_dir=t(og["light_dir"]),
            falloff=t(1.0 / np.maximum(og["dist"], 1e-9) ** 2),
            light_intensity=t(np.broadcast_to(self.intensity, (M, 3))),
            view_dir=t(og["view_dir"]),
            kappa=t(self.kappa),
            source=f"{self.run.folder}: predicted lights",
        )

    def fitted_observations(self, chunk: int) -> Iterator[Observations]:
        """The geometry of the run's own fitted lights, chunk lights at a time."""
        for start in range(0, len(self.lights), chunk):
            yield self.observations(self.lights[start : start + chunk])


@dataclass
class TexelEstimate:
    """A run's estimate over the T texels of its geometry (RunScene's fields of the same names)."""

    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    estimated: torch.Tensor
    unobserved: torch.Tensor
    lobe_measured: torch.Tensor
    n_specular: torch.Tensor


def texel_estimate(run: RunResult, index: np.ndarray, dtype: torch.dtype) -> TexelEstimate:
    """The run's maps at the texels' flat grid indices index (T,), in dtype: the estimate, the stand-in (the
    estimated texels' median, per channel) at the unobserved texels (module docstring), 0 at the other texels
    without one. A run without a coverage map has no unobserved texel."""
    grid = lambda a: np.asarray(a).reshape(-1, *np.shape(a)[2:])[index]
    estimated = torch.from_numpy(grid(run.mask))
    coverage = None if run.coverage is None else torch.from_numpy(grid(run.coverage).astype(np.int64))
    # without a coverage map the texels set aside (untrusted, misfit) cannot be told from the unobserved: none is
    unobserved = torch.zeros_like(estimated) if coverage is None else ~estimated & (coverage == COVER_NONE)
    unobserved &= bool(estimated.any())  # no stand-in without an estimated texel
    if run.lobe_measured is not None:
        lobe = torch.from_numpy(grid(run.lobe_measured)) & estimated
    elif coverage is not None:
        lobe = (coverage == COVER_FULL) & estimated
    else:
        lobe = torch.zeros_like(estimated)
    n_spec = torch.from_numpy(grid(run.n_specular)) if run.n_specular is not None else lobe * 2
    maps = []
    for a in (run.pd, run.ps, run.sigma):
        x = torch.from_numpy(grid(a)).to(dtype)
        x = torch.where(estimated.view(-1, *[1] * (x.dim() - 1)), x, 0.0)
        if unobserved.any():
            x[unobserved] = x[estimated].median(0).values
        maps.append(x)
    return TexelEstimate(*maps, estimated, unobserved, lobe, n_spec.long())


def capture_folder(run: RunResult, cfg: Config) -> Path:
    """The scan folder a run was fitted on: a synthetic run's `capture/`, a cylindrical_scan's capture.path."""
    if cfg.capture.kind not in SCAN_KINDS:
        raise ConfigError(
            f"{run.folder / CONFIG}: capture.kind is '{cfg.capture.kind}'; the next-best light planner reads runs of "
            f"{' or '.join(SCAN_KINDS)} (head-frame light positions)"
        )
    folder = (
        run.folder / "capture" if cfg.capture.kind == "synthetic_cylindrical" else resolve_path(cfg, cfg.capture.path)
    )
    if not (folder / "scan.yaml").is_file():
        raise RunFolderError(f"{folder / 'scan.yaml'}: missing (expected the scan the run {run.folder} was fitted on)")
    return folder


def run_noise(run: RunResult, cfg: Config) -> torch.Tensor:
    """(3,) the run's sensor noise in DN: metrics.json uncertainty.noise_dn, else capture.noise_dn."""
    block = run.metrics.get("uncertainty")
    noise = block.get("noise_dn") if isinstance(block, dict) else None
    if isinstance(noise, list) and len(noise) == 3 and all(isinstance(x, (int, float)) and x > 0 for x in noise):
        return torch.tensor(noise, dtype=torch.float64)
    if cfg.capture.noise_dn is not None and cfg.capture.noise_dn > 0:
        return torch.full((3,), float(cfg.capture.noise_dn), dtype=torch.float64)
    raise RunFolderError(
        f"{run.folder / 'metrics.json'}: no 'uncertainty.noise_dn' (3 values > 0) and config.yaml has no "
        "capture.noise_dn: the planner needs the sensor noise (refit with this version, or set capture.noise_dn)"
    )


def load_run_scene(run_dir: str | Path) -> RunScene:
    """The RunScene of a finished run folder (RunFolderError: not a run folder, an incomplete or damaged run)."""
    run = load_run(run_dir)
    cfg = load_config(run.folder / CONFIG)
    folder = capture_folder(run, cfg)
    geometry = CylindricalScanLoader().load_geometry(folder, cfg, check_scale=False)
    index = geometry.surface.texel_index.numpy()
    if tuple(geometry.surface.grid_shape) != run.grid_shape:
        raise RunFolderError(
            f"{folder}: its grid {tuple(geometry.surface.grid_shape)} is not the run's {run.grid_shape} (params.npz)"
        )
    est = texel_estimate(run, index, cfg.torch_dtype)  # the fit's dtype (what its uncertainty was computed in)
    doc = read_scan_yaml(folder)
    entries = doc["lights"]
    subset = cfg.capture.light_subset
    entries = [entries[i] for i in subset] if subset is not None else entries
    fitted = ~held_out(cfg.fit.holdout, len(entries)).numpy()
    lights = np.array([e["position_mm"] for e in entries], dtype=np.float64).reshape(-1, 3)[fitted]
    rc = cfg.reflectance
    return RunScene(
        run=run,
        cfg=cfg,
        geometry=geometry,
        pd=est.pd,
        ps=est.ps,
        sigma=est.sigma,
        estimated=est.estimated,
        unobserved=est.unobserved,
        lobe_measured=est.lobe_measured,
        n_specular=est.n_specular,
        lights=lights,
        intensity=np.asarray(doc["light"]["intensity"], dtype=np.float64),
        kappa=np.asarray(run.kappa, dtype=np.float64),
        saturation_level=float(doc.get("saturation_level", DEFAULT_SATURATION)),
        noise_dn=run_noise(run, cfg),
        ranges=ParameterRanges(rc.ps_max, rc.sigma_min, rc.sigma_max),
    )
