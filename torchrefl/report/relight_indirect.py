"""The interreflection of a relit frame: the indirect light the run's transport level computes for a new light.

A radiosity or photon run (metrics.json `model`) modelled the light the object reflects onto itself. Relighting it
under a light the capture did not have adds that light too, computed by the level itself (transport.levels), from
the fitted parameters, on the capture's own texel Surface:

- the Surface is rebuilt from the run: a mesh_views run's atlas (geometry.atlas_surface.atlas_geometry of the mesh
  params.npz names, at its texture size, as the loader builds it), a scan's grid (its texel positions and normals,
  the grid triangulation the relighting traces, geometry.range_mesh.texel_areas);
- one observation per texel for the new light: its direction, falloff and cast shadow (core.point_light, the
  relighting's shadow offset), the view direction towards the camera's centre (a pinhole) or against its axis
  (orthographic), the run's kappa;
- the level's own machinery on them: radiosity, the diffuse interreflection H of the radiosity solution
  (RadiosityLevel.indirect; its form factors, traced once per run, are the surface's and serve every light); photon,
  a PhotonLevel on the same observations (its radiosity part for the all-diffuse paths, photons traced from the new
  light for the paths with a specular scattering, the specular gather), whose images average
  transport.final_traces.FINAL_TRACES independent traces (no photon noise is measured for a new light). The
  specular part is reduced toward each texel's view direction, so the glossy interreflection is seen from the new
  camera;
- texels without an estimate reflect with the nearest estimated texel's parameters (fit.emitter_fill, as in the
  fit).

The result is each texel's indirect sensor value (the level's image minus its local part), which the relighting
samples at every hit with the weights it samples the parameters with (report.hit_texels) and adds to the direct
light, shadowed hits included. What is left out: the indirect light is the texel's (its own normal and one view
direction per texel, not per pixel), and a photon run lit by a directional light has no photon source (refused).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from torchrefl.config import Config, load_config
from torchrefl.core.observation_classes import classify
from torchrefl.core.observations import Observations
from torchrefl.core.point_light import light_geometry
from torchrefl.core.surface import Surface
from torchrefl.core.texel_grid import TexelGrid
from torchrefl.errors import CaptureError, RunFolderError
from torchrefl.fit.emitter_fill import nearest_fitted
from torchrefl.geometry.atlas_surface import atlas_geometry
from torchrefl.geometry.range_mesh import texel_areas
from torchrefl.report.hit_texels import geometry_mask
from torchrefl.transport.levels.auto import prepare
from torchrefl.transport.levels.base import LevelInputs
from torchrefl.transport.levels.photon import PhotonLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel
from torchrefl.transport.local import local_terms
from torchrefl.transport.radiosity_level import reflected_indirect

#: the transport levels that model interreflection (metrics.json `model`)
INTERREFLECTION_LEVELS = ("radiosity", "photon")
#: the dtype of the level's computation (the photon cache and the radiosity solve)
DTYPE = torch.float64


def run_level(run) -> str:
    """The transport level a run was fitted with (metrics.json `model`: local, radiosity or photon)."""
    return str(run.metrics.get("model", "local"))


@dataclass
class IndirectModel:
    """What a run's interreflection is computed from, for any light: the run's resolved Config, its level name,
    the capture's texel Surface, the fitted parameters at its texels pd (T, 3), ps (T, C), sigma (T,) (float64),
    emitters (T,) the texel whose parameters each texel reflects with (None: its own), the camera gain kappa (3,)
    and the radiosity level, prepared once (its form factors)."""

    cfg: Config
    level: str
    surface: Surface
    kappa: np.ndarray
    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    emitters: torch.Tensor | None
    radiosity: RadiosityLevel | None = None
    #: the last frame's light, view directions and indirect values (T, 3): frames that differ only in the pixels'
    #: sampling (supersample, interpolation, shadows) reuse them
    last: tuple | None = None


def run_surface(run, mesh) -> Surface:
    """The capture's texel Surface of a run (module doc); mesh: its report.hit_texels.TexelMesh (the atlas mesh
    of a mesh_views run, a scan's grid triangulation). RunFolderError when the rebuilt texels are not the run's."""
    valid = geometry_mask(run.normals)
    if mesh.atlas is not None:
        surface = atlas_geometry(mesh.atlas.mesh, run.grid_shape[0]).surface
    else:
        idx = np.flatnonzero(valid.ravel())
        positions = np.asarray(run.positions, np.float64)
        normals = np.asarray(run.normals, np.float64).reshape(-1, 3)[idx]
        surface = Surface(
            grid_shape=run.grid_shape,
            texel_index=torch.from_numpy(idx),
            positions=torch.from_numpy(positions.reshape(-1, 3)[idx]),
            normals=torch.from_numpy(normals / np.linalg.norm(normals, axis=1, keepdims=True)),
            areas=torch.from_numpy(texel_areas(positions, valid).ravel()[idx]),
            mesh_vertices=mesh.vertices,
            mesh_faces=mesh.faces,
            units=run.units,
            source=str(run.folder / "params.npz"),
            neighbours=TexelGrid(idx, run.grid_shape, wrap=mesh.wrap),
        )
    if not np.array_equal(surface.texel_index.numpy(), np.flatnonzero(valid.ravel())):
        raise RunFolderError(
            f"{run.folder / 'params.npz'}: its texels with geometry ({int(valid.sum())}) are not those of the mesh's "
            f"atlas rebuilt at {run.grid_shape[0]} ({surface.num_texels}): expected the mesh the run was fitted on"
        )
    return surface


def indirect_model(run, mesh) -> IndirectModel:
    """The IndirectModel of a radiosity or photon run (mesh: as run_surface)."""
    level = run_level(run)
    path = run.folder / "config.yaml"
    try:
        cfg = load_config(Path(path))
    except Exception as exc:  # a ConfigError naming the key, or an unreadable file
        raise RunFolderError(f"{path}: the run's config cannot be read for its {level} level ({exc})") from None
    cfg.output.progress = False  # the frame's own progress bar counts the rays
    surface = run_surface(run, mesh)
    idx = surface.texel_index.numpy()
    at = lambda a: torch.from_numpy(np.asarray(a, np.float64).reshape(len(run.mask.ravel()), -1)[idx]).to(DTYPE)
    estimated = torch.from_numpy(run.mask.ravel()[idx])
    if not bool(estimated.any()):
        raise RunFolderError(f"{run.folder / 'params.npz'}: 'mask' selects no texel, so nothing reflects light")
    source = nearest_fitted(surface.positions, estimated)
    emitters = None if bool((source == torch.arange(len(source))).all()) else source
    return IndirectModel(
        cfg, level, surface, np.asarray(run.kappa, np.float64), at(run.pd), at(run.ps), at(run.sigma)[:, 0], emitters
    )


def view_directions(camera, index: int, positions: np.ndarray) -> np.ndarray:
    """(T, 3) unit directions from texel positions (T, 3) towards the camera (Cameras: camera `index`, towards its
    centre; an OrthographicCamera: against its viewing axis)."""
    if hasattr(camera, "pixel_size"):  # report.relight_camera.OrthographicCamera
        return np.broadcast_to(-np.asarray(camera.R, np.float64)[2], positions.shape).copy()
    to = camera.centres()[index].double().numpy()[None] - positions
    return to / np.maximum(np.linalg.norm(to, axis=1, keepdims=True), 1e-300)


def light_observations(model: IndirectModel, light, views: np.ndarray, tracer, offset: float) -> Observations:
    """One observation per texel of model.surface under `light` (report.relight.Light) seen along views (T, 3),
    with its cast shadows (tracer, offset: core.point_light)."""
    s = model.surface
    x, n = s.positions.double().numpy(), s.normals.double().numpy()
    lit = light_geometry(x, n, tracer, position=light.position, direction=light.direction, offset=offset)
    T = s.num_texels
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=DTYPE)
    return Observations(
        intensity=torch.zeros(1, T, 3, dtype=DTYPE),
        valid=torch.ones(1, T, dtype=torch.bool),
        saturated=torch.zeros(1, T, dtype=torch.bool),
        shadowed=torch.from_numpy(lit.shadowed)[None],
        light_dir=t(lit.direction)[None],
        falloff=t(lit.falloff)[None],
        light_intensity=t(light.intensity)[None],
        view_dir=t(views),
        kappa=t(model.kappa),
        light_positions=None if light.position is None else t(light.position)[None],
        source="relight light",
    )


def level_inputs(model: IndirectModel, obs: Observations) -> LevelInputs:
    """LevelInputs of the one-light observations: every texel facing the camera is 'fitted' (what the photon level
    reduces its view-dependent cache for); nothing is initialised."""
    rc = model.cfg.reflectance
    terms = local_terms(rc.brdf, model.surface.normals.to(DTYPE), obs)
    facing = terms.cos_v > 0
    classes = classify(terms.theta_h, facing, rc.theta_diffuse_deg, rc.theta_specular_deg)

    def no_start(_):
        raise RuntimeError("a relighting level is not initialised")

    return LevelInputs(
        model.cfg,
        model.surface,
        obs,
        terms,
        classes,
        facing,
        torch.zeros_like(facing),
        torch.device("cpu"),
        lambda _message: None,
        no_start,
    )


def indirect_values(model: IndirectModel, obs: Observations) -> torch.Tensor:
    """(T, 3) each texel's indirect sensor value under the one light of obs (module doc)."""
    inputs = level_inputs(model, obs)
    pd, ps, sigma = model.pd, model.ps, model.sigma
    if model.radiosity is None:
        model.radiosity = RadiosityLevel(inputs)
        if model.emitters is not None:
            model.radiosity.use_emitters(model.emitters)
        prepare(model.radiosity)
    radiosity = model.radiosity.for_observations(inputs)
    with torch.no_grad():
        if model.level == "radiosity":
            return reflected_indirect(obs.kappa, pd, radiosity.indirect(pd))[0]
        if obs.light_positions is None:
            raise CaptureError(
                "render light: the run's photon level traces photons from point lights, and this light is "
                "directional: give a point light, or interreflection=False (--no-interreflection)"
            )
        level = PhotonLevel(inputs, radiosity)
        if model.emitters is not None:
            level.use_emitters(model.emitters)
        level.prepare()
        level.cache = level.refresher.cache(pd, ps, sigma, refresh=0)
        return (level.render(pd, ps, sigma) - inputs.local_predict()(pd, ps, sigma))[0]


def indirect_grid(model: IndirectModel, light, camera, index: int, tracer, offset: float) -> np.ndarray:
    """(H * W, 3) the texels' indirect sensor values on the run's grid (0 where the grid has no texel) for light
    seen by camera (module doc)."""
    s = model.surface
    views = view_directions(camera, index, s.positions.double().numpy())
    key = [light.intensity, light.position, light.direction, views]
    same = model.last is not None and all(
        (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))
        for a, b in zip(key, model.last[0])
    )
    if same:
        values = model.last[1]
    else:
        values = indirect_values(model, light_observations(model, light, views, tracer, offset))
        model.last = (key, values)
    H, W = s.grid_shape
    out = np.zeros((H * W, 3))
    out[s.texel_index.numpy()] = values.double().numpy()
    return out
