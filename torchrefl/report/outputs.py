"""A run's output files: params.npz, metrics.json and the maps (the contract: docs/outputs.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.atomic_files import atomic_file, atomic_write_text
from torchrefl.core.memory import peak_device_mb, peak_resident_mb
from torchrefl.core.progress import Stages
from torchrefl.fit.initialise import COVER_UNTRUSTED
from torchrefl.fit.result import FitResult
from torchrefl.geometry.mesh_file import write_obj
from torchrefl.planning.light_selection import SelectionResult
from torchrefl.report.coverage import specular_sources
from torchrefl.report.export_mesh import atlas_mesh, scan_mesh
from torchrefl.report.export_run import EXPORT, ExportInput, export_estimate
from torchrefl.report.figure import write_figure
from torchrefl.report.maps import write_light_maps, write_parameter_maps
from torchrefl.report.metrics import ground_truth_errors, image_difference, strict_json
from torchrefl.report.uncertainty import relative_maps, uncertainty_summary, write_uncertainty_maps
from torchrefl.version import __version__

MESH = "mesh.obj"  # the mesh the maps lie on, in the run folder when torchrefl made its atlas


def mesh_of_maps(out: Path, cap: Capture) -> str | None:
    """params.npz's `mesh`: the mesh whose atlas the maps lie on (mesh_views), None for the other kinds. A mesh
    whose atlas torchrefl made (xatlas) is written into the run folder as mesh.obj; a mesh inside the run folder
    (a synthetic capture) is named relative to it, any other by its absolute path."""
    if cap.mesh is None:
        return None
    if cap.mesh_parametrised:
        write_obj(out / MESH, cap.mesh)
        return MESH
    source = Path(cap.mesh.source).resolve()
    try:
        return source.relative_to(out.resolve()).as_posix()
    except ValueError:
        return str(source)


def grid_faces(cap: Capture) -> np.ndarray | None:
    """params.npz's `grid_faces`: the range mesh's triangles over the texel grid's points (vertex r * W + c) of a
    capture whose mesh is its grid triangulation (cylindrical_scan); None for the other kinds."""
    surface = cap.surface
    H, W = surface.grid_shape
    if cap.mesh is not None or not surface.has_mesh or len(surface.mesh_vertices) != H * W:
        return None
    return np.asarray(surface.mesh_faces, dtype=np.int32)


def export_input(cap: Capture, res: FitResult, brdf: str) -> ExportInput:
    """The run's estimate and mesh as report.export_run takes them."""
    surface = cap.surface
    grid = lambda x, fill=0.0: surface.to_grid(x, fill=fill)
    positions, normals = grid(surface.positions.double()), grid(surface.normals.double())
    faces = grid_faces(cap)
    mesh = scan_mesh(positions, normals, faces, surface.units) if faces is not None else None
    mesh = atlas_mesh(cap.mesh) if cap.mesh is not None else mesh
    return ExportInput(
        grid(res.pd.double().numpy()),
        grid(res.ps.double().numpy()),
        grid(res.sigma.double().numpy()),
        surface.to_grid(res.estimated.numpy(), fill=False),
        np.asarray(normals),
        grid(res.coverage.numpy()),
        brdf,
        mesh,
        str(surface.source),
    )


def write_params(path: Path, cfg: Config, cap: Capture, res: FitResult, mesh: str | None = None) -> None:
    """params.npz: the estimate and the texel geometry on the texel grid (with `mesh`, the mesh it lies on)."""
    surface, obs = cap.surface, cap.obs
    grid = lambda x, fill=0.0: surface.to_grid(x, fill=fill)
    faces = grid_faces(cap)
    with atomic_file(path) as fh:
        np.savez_compressed(
            fh,
            pd=grid(res.pd.float()),
            ps=grid(res.ps.float()),
            sigma=grid(res.sigma.float()),
            mask=surface.to_grid(res.estimated.numpy(), fill=False),
            brdf=np.array(cfg.reflectance.brdf),
            positions=grid(surface.positions.float()),
            normals=grid(surface.normals.float()),
            coverage=grid(res.coverage),
            n_diffuse=grid(res.counts["T_diff"].to(torch.int16)),
            n_specular=grid(res.counts["T_spec"].to(torch.int16)),
            kappa=obs.kappa.numpy(),
            units=np.array(surface.units),
            diffuse=np.array(res.diffuse.model),
            minnaert_k=np.array(res.diffuse.k),
            **({"mesh": np.array(mesh)} if mesh is not None else {}),
            **({"grid_faces": faces} if faces is not None else {}),
            **uncertainty_arrays(surface, res),
        )


def uncertainty_arrays(surface, res: FitResult) -> dict:
    """params.npz's pd_std, ps_std, sigma_std and lobe_measured on the texel grid (none without an uncertainty)."""
    u = res.uncertainty
    if u is None:
        return {}
    grid = lambda x: surface.to_grid(x.float(), fill=0.0)
    return {
        "pd_std": grid(u.pd_std),
        "ps_std": grid(u.ps_std),
        "sigma_std": grid(u.sigma_std),
        "lobe_measured": surface.to_grid((u.lobe_measured & res.estimated).numpy(), fill=False),
    }


def metrics_of(cfg: Config, cap: Capture, res: FitResult, selection: SelectionResult | None, device: str) -> dict:
    """metrics.json's content, without the maps and the timing."""
    obs = cap.obs
    metrics = {
        "version": __version__,
        "model": res.level,
        "model_reason": res.model_reason,
        "model_numbers": res.model_numbers,
        **({"photon": res.photon} if res.photon else {}),
        "brdf": cfg.reflectance.brdf,
        "diffuse": {**res.diffuse.as_dict(), **({"k_true": cap.truth["minnaert_k"]} if cap.truth else {})},
        "capture": {
            "kind": cfg.capture.kind,
            **{k: v for k, v in cap.stats.items() if isinstance(v, (int, float, str))},
            "warnings": list(cap.warnings),
        },
        "texels": cap.surface.num_texels,
        "lights": obs.num_lights,
        "holdout_lights": list(cfg.fit.holdout),
        "rerender": image_difference(res.predicted, obs.intensity, res.fit_mask),
        "coverage": {
            **res.init_counts,
            "estimated": int(res.estimated.sum()),
            "misfit": res.misfit,
            "untrusted_geometry": int((res.coverage == COVER_UNTRUSTED).sum()),
        },
        "specular_source": specular_source(cap, res),
        "fit": {
            "optimizer": res.optimizer,
            "loss_first": res.history[0],
            "loss_last": res.history[-1],
            "evaluations": len(res.history),
        },
        "device": device,
        "dtype": cfg.dtype,
    }
    if cfg.fit.holdout:
        metrics["holdout"] = image_difference(res.predicted, obs.intensity, res.eval_mask)
        metrics["holdout"]["unestimated_observations"] = res.holdout_unestimated
    if cap.truth is not None:
        spec2 = res.counts["T_spec"] >= 2
        metrics["ground_truth"] = ground_truth_errors(res.pd, res.ps, res.sigma, cap.truth, res.estimated, spec2)
    if res.uncertainty is not None:
        metrics["uncertainty"] = uncertainty_summary(res.ps, res.sigma, res.uncertainty, res.estimated)
    if selection is not None:
        metrics["selection"] = selection.table()
    return metrics


def specular_source(cap: Capture, res: FitResult) -> dict:
    """metrics.json's specular_source block (torchrefl.report.coverage), per truth region where the truth has them."""
    surface = cap.surface
    region = cap.truth.get("region") if cap.truth else None
    return specular_sources(
        surface.to_grid(res.coverage.numpy(), fill=0),
        surface.to_grid(res.estimated.numpy(), fill=False),
        None if region is None else surface.to_grid(np.asarray(region), fill=-1),
    )


def write_outputs(
    cfg: Config, out: Path, cap: Capture, res: FitResult, selection: SelectionResult | None, stages: Stages, device: str
) -> dict:
    """Write params.npz, the maps and metrics.json into `out`; returns the metrics."""
    surface, obs = cap.surface, cap.obs
    grid = lambda x, fill=0.0: surface.to_grid(x, fill=fill)
    with stages.stage("outputs"):
        write_params(out / "params.npz", cfg, cap, res, mesh_of_maps(out, cap))
        metrics = metrics_of(cfg, cap, res, selection, device)
        maps = out / "maps"
        mask = surface.to_grid(res.estimated.numpy(), fill=False)
        estimate = (grid(res.pd.double().numpy()), grid(res.ps.double().numpy()), grid(res.sigma.double().numpy()))
        coverage = grid(res.coverage.numpy())
        metrics["maps"] = write_parameter_maps(maps, mask, *estimate, coverage, cfg.reflectance.sigma_max)
        stds = uncertainty_arrays(surface, res)
        lobe = stds.pop("lobe_measured", None)
        metrics["maps"].update(write_uncertainty_maps(maps, mask, stds))
        # the run folder's name: `out` is its staging folder
        title = f"{Path(cfg.output.dir).name}: model {res.level}, brdf {cfg.reflectance.brdf}"
        relative = None if lobe is None else relative_maps(estimate[1], estimate[2], stds, lobe)
        write_figure(maps / "figure.png", *estimate, mask, coverage, cfg.reflectance.sigma_max, title, relative)
        k = min(cfg.output.map_lights, obs.num_lights)
        for p in np.linspace(0, obs.num_lights - 1, k).round().astype(int) if k else []:
            shown = surface.to_grid(obs.valid[p].numpy(), fill=False)
            write_light_maps(
                maps,
                f"light_{p:03d}",
                grid(obs.intensity[p].double().numpy()),
                grid(res.predicted[p].double().numpy()),
                shown,
            )
    if cfg.output.export:
        with stages.stage("export"):
            export_estimate(export_input(cap, res, cfg.reflectance.brdf), out / EXPORT, option="output.export")
    metrics["timing_s"] = {k: round(v, 3) for k, v in stages.timing.items()}
    metrics["timing_s"]["total"] = round(stages.total(), 3)
    metrics["cpu_s"] = {k: round(v, 3) for k, v in stages.cpu.items()}
    metrics["cpu_s"]["total"] = round(sum(stages.cpu.values()), 3)
    metrics["peak_memory_mb"] = round(peak_resident_mb(), 1)
    gpu = peak_device_mb(torch.device(device))
    if gpu is not None:
        metrics["peak_gpu_memory_mb"] = round(gpu, 1)
    atomic_write_text(out / "metrics.json", strict_json(metrics))
    return metrics
