"""A finished run's outputs, for notebooks and other tools.

    from torchrefl.report.run_result import load_run
    run = load_run("outputs/default")
    print(run.summary())                 # the table the CLI prints at the end
    run.figure()                         # Pd, Ps, sigma and coverage maps (matplotlib)
    img = run.render(light_position=(0, 200, 400), camera=(0, 0, 300))   # relight the texel grid
    from torchrefl.report.relight import Light
    from torchrefl.report.relight_camera import orbit_camera
    cam = orbit_camera(run.scene.centre, run.scene.radius, 30, 20, 300)   # a pinhole camera (capture.cameras)
    frame = run.render(camera=cam, light=Light(intensity=2e5, position=(0, 200, 400))).image   # with cast shadows
    run.export("outputs/default_export")   # OBJ + MTL, glTF .glb, 16-bit PNG and EXR maps (docs/exports.md)

`load_run` reads the outputs contract (docs/outputs.md) (params.npz, metrics.json, config.yaml) and
checks it: a folder without a valid completeness marker (torchrefl.report.run_marker: an incomplete run),
a recorded file changed or missing, a missing key, a wrong shape or a non-finite parameter is a
RunFolderError naming the file and what was expected. Files the marker does not record (a user's own, kept
beside the run's) are ignored and listed in `unrecorded` and in the summary.
Maps are on the texel grid (H, W); texels outside `mask` (no estimate) are 0 in the arrays and
blank in the figure.

`render(camera=CAMERA, light=LIGHT)` is the image of the fitted object from a pinhole (capture.cameras.Cameras) or
orthographic camera under a point or directional light, with cast shadows and the interreflection the run's level
models (radiosity, photon; `interreflection=False` for direct light only) (torchrefl.report.relight). Without
`light`, `render(light_position=..., camera=(x, y, z))` shades the estimated texels on the texel grid under one new
light with the fitted BRDF, through the fitter's own observation model (torchrefl.transport.local.render_reference:
i = kappa * Y * falloff * g(n, l, v)): local transport only (no cast shadows, no interreflection), a preview of the
estimate on its grid.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch
import yaml

from torchrefl.core import brdf as brdf_mod
from torchrefl.errors import CaptureError, RunFolderError
from torchrefl.report.relight import relight, relight_scene, shade
from torchrefl.report.run_marker import unrecorded_files, verify_run_folder

PARAMS = "params.npz"
METRICS = "metrics.json"
CONFIG = "config.yaml"
REQUIRED_KEYS = ("pd", "ps", "sigma", "mask", "brdf", "positions", "normals", "kappa")
SHOWN_UNRECORDED = 5  # the summary names at most this many files the run did not write
METRICS_KEYS = {"model": str, "brdf": str, "texels": int, "lights": int, "timing_s": dict, "rerender": dict}


@dataclass
class RunResult:
    """The estimate of one run on its texel grid (H, W).

    pd (H, W, 3), ps (H, W, C) with C in {1, 3}, sigma (H, W): the reflectance; mask (H, W) bool: texels
    with an estimate; positions, normals (H, W, 3): the texel geometry (world frame, `units`);
    coverage (H, W): how each texel was determined (torchrefl.report.maps); n_diffuse, n_specular (H, W):
    observations per texel in T_diff and T_spec; kappa (3,): the camera gain; brdf: the model name;
    diffuse, minnaert_k: the diffuse part (lambert, or minnaert with its exponent; 1 = Lambert);
    metrics: metrics.json; config: the resolved config.yaml as a dict; unrecorded: the folder's files that the
    run did not write (relative paths; ignored); mesh: params.npz's `mesh` (mesh_views: the mesh whose atlas the
    maps are), None for the other kinds; pd_std (H, W, 3), ps_std (H, W, C), sigma_std (H, W): the parameters' std,
    lobe_measured (H, W) bool: Ps and sigma estimated from the texel's own observations (torchrefl.fit.uncertainty;
    None in runs without them).
    """

    folder: Path
    pd: np.ndarray
    ps: np.ndarray
    sigma: np.ndarray
    mask: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    kappa: np.ndarray
    brdf: str
    units: str
    coverage: np.ndarray | None
    n_diffuse: np.ndarray | None
    n_specular: np.ndarray | None
    metrics: dict
    config: dict
    diffuse: str = "lambert"
    minnaert_k: float = 1.0
    unrecorded: tuple[str, ...] = ()
    mesh: str | None = None
    pd_std: np.ndarray | None = None
    ps_std: np.ndarray | None = None
    sigma_std: np.ndarray | None = None
    lobe_measured: np.ndarray | None = None

    @cached_property
    def scene(self):
        """The run's RelightScene (torchrefl.report.relight): its mesh and Embree scene, built on first use."""
        return relight_scene(self)

    @property
    def grid_shape(self) -> tuple[int, int]:
        return tuple(self.mask.shape)

    def summary(self) -> str:
        """The summary table the command line prints at the end of the run, and the files in the folder that the
        run did not write (when there are any)."""
        from torchrefl.report.summary import summary_table

        table = summary_table(self.metrics)
        if not self.unrecorded:
            return table
        shown = ", ".join(self.unrecorded[:SHOWN_UNRECORDED]) + (
            ", ..." if len(self.unrecorded) > SHOWN_UNRECORDED else ""
        )
        return f"{table}\n  {len(self.unrecorded)} file(s) in the folder not written by the run (ignored): {shown}"

    def render(
        self,
        *,
        light_position=None,
        light_direction=None,
        intensity=1.0,
        camera=None,
        view_dir=None,
        dtype=torch.float64,
        light=None,
        **options,
    ):
        """With `light` (torchrefl.report.relight.Light): the RelitImage of the object seen by `camera` (a
        capture.cameras.Cameras, its camera `index=`, or a relight_camera.OrthographicCamera), with cast shadows and,
        for a radiosity or photon run, its level's interreflection; options: relight.relight's (supersample, shadows,
        interpolation, progress, index, interreflection: False for direct light only).

        Without `light`: (H, W, 3) predicted sensor values (fractions of full range) of the estimated texels under
        one light, on the texel grid.

        The light: light_position (3,) a point light (falloff 1 / C^2) or light_direction (3,) a directional
        light towards the light; intensity: its radiant intensity Y > 0, a scalar or RGB (3,), in the capture's
        units (metrics.json and the capture's light table). The camera: camera (3,) a pinhole position, or
        view_dir (3,) or (H, W, 3) the direction towards the camera (orthographic; photometric stereo: (0, 0, 1)).
        Texels outside `mask` or facing away from the light or the camera are 0.
        """
        if light is not None:
            if light_position is not None or light_direction is not None or view_dir is not None:
                raise CaptureError(
                    "RunResult.render: with light=Light(...), give the camera as camera=...; light_position, "
                    "light_direction and view_dir belong to the grid render (without light=)"
                )
            return relight(self, camera, light, scene=self.scene, **options)
        if options:
            raise CaptureError(f"RunResult.render: option(s) {', '.join(options)} need light=Light(...)")
        if (light_position is None) == (light_direction is None):
            raise CaptureError(
                "RunResult.render: give exactly one of light_position=(x, y, z) (a point light) "
                "and light_direction=(x, y, z) (a directional light)"
            )
        if (camera is None) == (view_dir is None):
            raise CaptureError(
                "RunResult.render: give exactly one of camera=(x, y, z) (a pinhole camera) and "
                "view_dir=(x, y, z) or an (H, W, 3) array (an orthographic camera)"
            )
        m = torch.from_numpy(self.mask)
        t = lambda a: torch.as_tensor(np.array(a, dtype=np.float64), dtype=dtype)
        x, n = t(self.positions)[m], t(self.normals)[m]
        Y = _vector("intensity", intensity, allow_scalar=True).to(dtype)
        if light_position is not None:
            to = _vector("light_position", light_position).to(dtype) - x
            dist2 = (to * to).sum(-1)
            if not bool((dist2 > 0).all()):
                raise CaptureError("RunResult.render: light_position lies on an estimated texel (distance 0)")
            l, falloff = to / dist2.sqrt()[:, None], 1.0 / dist2
        else:
            l = brdf_mod.safe_normalize(_vector("light_direction", light_direction, unit=True).to(dtype)).expand_as(x)
            falloff = torch.ones(len(x), dtype=dtype)
        if camera is not None:
            v = brdf_mod.safe_normalize(_vector("camera", camera).to(dtype) - x)
        else:
            vd = np.asarray(view_dir, dtype=np.float64)
            if vd.shape == (3,):
                v = brdf_mod.safe_normalize(_vector("view_dir", vd, unit=True).to(dtype)).expand_as(x)
            elif vd.shape == self.grid_shape + (3,):
                v = brdf_mod.safe_normalize(t(vd)[m])
            else:
                raise CaptureError(
                    f"RunResult.render: view_dir has shape {vd.shape}, expected (3,) or {self.grid_shape + (3,)}"
                )
        # one light through the fitter's own observation model (transport.local)
        values = shade(self, n, l, falloff, v, Y, t(self.pd)[m], t(self.ps)[m], t(self.sigma)[m])
        values = values * (brdf_mod.dot(n, v) > 0).to(dtype)[:, None]
        out = np.zeros(self.grid_shape + (3,))
        out[self.mask] = values.numpy()
        return out

    def export(self, out_dir, formats=None):
        """Write the run's exports into out_dir (docs/exports.md): OBJ + MTL, glTF .glb, 16-bit PNG and OpenEXR
        maps; formats: some of "maps", "obj", "glb" (None: every format the run's geometry allows). Returns an
        ExportResult (torchrefl.report.export_run)."""
        from torchrefl.report.export_run import export_run

        return export_run(self, out_dir, formats)

    def figure(self, sigma_max: float | None = None):
        """A matplotlib Figure (pyplot) with Pd (sRGB), Ps (mean over channels), sigma and the coverage map
        (torchrefl.report.figure), and where the run has them the relative std of Ps and sigma
        (torchrefl.report.uncertainty); sigma_max: the top of sigma's colour range, by default the run's
        reflectance.sigma_max."""
        import matplotlib.pyplot as plt

        from torchrefl.report.figure import described_texels, draw_reflectance, figure_size
        from torchrefl.report.uncertainty import relative_maps

        section = self.config.get("reflectance")
        top = sigma_max if sigma_max is not None else section.get("sigma_max") if isinstance(section, dict) else None
        top = top if isinstance(top, (int, float)) and not isinstance(top, bool) else None
        relative = None
        if self.lobe_measured is not None:
            stds = {"ps_std": self.ps_std, "sigma_std": self.sigma_std}
            relative = relative_maps(self.ps, self.sigma, stds, self.lobe_measured & self.mask)
        rows = 2 if relative is None else 3
        size = figure_size(described_texels(self.mask, self.coverage), rows)
        fig = plt.figure(figsize=size, layout="constrained")
        title = f"{self.folder.name}: model {self.metrics.get('model', '?')}, brdf {self.brdf}"
        return draw_reflectance(fig, self.pd, self.ps, self.sigma, self.mask, self.coverage, top, title, relative)


def _vector(name: str, value, allow_scalar: bool = False, unit: bool = False) -> torch.Tensor:
    a = np.asarray(value, dtype=np.float64)
    if allow_scalar and a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,) or not np.isfinite(a).all():
        raise CaptureError(
            f"RunResult.render: {name}={value!r}, expected 3 finite numbers" + (" or one" if allow_scalar else "")
        )
    if allow_scalar and (a <= 0).any():
        raise CaptureError(f"RunResult.render: {name}={value!r}, expected values > 0")
    if unit and not np.linalg.norm(a) > 0:
        raise CaptureError(f"RunResult.render: {name}={value!r} is the zero vector, expected a direction")
    return torch.from_numpy(a)


def _read_params(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as npz:
            p = {k: npz[k] for k in npz.files}
    except Exception as exc:  # a truncated or foreign file: say which and why
        raise RunFolderError(f"{path}: unreadable as a numpy .npz archive ({exc})") from None
    missing = [k for k in REQUIRED_KEYS if k not in p]
    if missing:
        raise RunFolderError(f"{path}: missing key(s) {', '.join(missing)} (expected {', '.join(REQUIRED_KEYS)})")
    mask = p["mask"]
    if mask.ndim != 2 or mask.dtype != bool:
        raise RunFolderError(f"{path}: 'mask' is {mask.dtype} {mask.shape}, expected a bool (H, W) grid")
    H, W = mask.shape
    expect = {"pd": (H, W, 3), "sigma": (H, W), "positions": (H, W, 3), "normals": (H, W, 3), "kappa": (3,)}
    for key, shape in expect.items():
        if p[key].shape != shape:
            raise RunFolderError(f"{path}: '{key}' has shape {p[key].shape}, expected {shape}")
    if p["ps"].shape not in ((H, W, 1), (H, W, 3)):
        raise RunFolderError(f"{path}: 'ps' has shape {p['ps'].shape}, expected ({H}, {W}, 1) or ({H}, {W}, 3)")
    for key in ("pd", "ps", "sigma", "positions", "normals"):
        a = p[key]
        if not np.issubdtype(a.dtype, np.number) or not np.isfinite(a[mask]).all():
            raise RunFolderError(
                f"{path}: '{key}' has NaN, infinite or non-numeric values at estimated texels "
                "(expected finite numbers inside 'mask')"
            )
    if not np.issubdtype(p["kappa"].dtype, np.number) or not (np.isfinite(p["kappa"]) & (p["kappa"] > 0)).all():
        raise RunFolderError(f"{path}: 'kappa' = {p['kappa'].tolist()}, expected 3 finite values > 0")
    return p


UNCERTAINTY_KEYS = ("pd_std", "ps_std", "sigma_std", "lobe_measured")


def _uncertainty(p: dict, path: Path) -> dict:
    """The std arrays of params.npz (torchrefl.fit.uncertainty), checked: all four or none, the shapes of pd, ps,
    sigma and mask, finite and >= 0 at estimated texels."""
    present = [k for k in UNCERTAINTY_KEYS if k in p]
    if not present:
        return {}
    if len(present) < len(UNCERTAINTY_KEYS):
        missing = ", ".join(k for k in UNCERTAINTY_KEYS if k not in p)
        raise RunFolderError(f"{path}: has {', '.join(present)} but not {missing} (expected all four or none)")
    mask = p["mask"]
    for key, of in (("pd_std", "pd"), ("ps_std", "ps"), ("sigma_std", "sigma"), ("lobe_measured", "mask")):
        if p[key].shape != p[of].shape:
            raise RunFolderError(f"{path}: '{key}' has shape {p[key].shape}, expected {p[of].shape} (as '{of}')")
    for key in UNCERTAINTY_KEYS[:3]:
        a = p[key]
        if not np.issubdtype(a.dtype, np.number) or not (np.isfinite(a[mask]) & (a[mask] >= 0)).all():
            raise RunFolderError(f"{path}: '{key}' expected finite values >= 0 inside 'mask'")
    return {k: p[k] if k != "lobe_measured" else p[k].astype(bool) for k in UNCERTAINTY_KEYS}


def _diffuse_part(p: dict, path: Path) -> tuple[str, float]:
    diffuse = str(p.get("diffuse", "lambert"))
    if diffuse not in ("lambert", "minnaert"):
        raise RunFolderError(f"{path}: 'diffuse' is {diffuse!r}, expected 'lambert' or 'minnaert'")
    raw = p.get("minnaert_k", np.array(1.0))
    if not np.issubdtype(raw.dtype, np.number) or raw.size != 1 or not np.isfinite(raw).all():
        raise RunFolderError(f"{path}: 'minnaert_k' is {raw!r}, expected one finite number")
    return diffuse, float(raw)


def _read_mapping(path: Path, reader, what: str) -> dict:
    try:
        data = reader(path.read_text())
    except Exception as exc:  # json / yaml / decoding errors: name the file
        raise RunFolderError(f"{path}: not valid {what} ({exc})") from None
    if not isinstance(data, dict):
        raise RunFolderError(f"{path}: expected a {what} mapping at the top level, got {type(data).__name__}")
    return data


def _read_metrics(path: Path, brdf: str) -> dict:
    metrics = _read_mapping(path, json.loads, "JSON")
    for key, kind in METRICS_KEYS.items():
        if not isinstance(metrics.get(key), kind) or isinstance(metrics.get(key), bool):
            raise RunFolderError(
                f"{path}: key '{key}' is {metrics.get(key)!r}, expected {kind.__name__} "
                "(metrics.json of a torchrefl run)"
            )
    timing = metrics["timing_s"]
    if "total" not in timing or not all(isinstance(v, (int, float)) for v in timing.values()):
        raise RunFolderError(f"{path}: key 'timing_s' must map stages (and 'total') to seconds, got {timing!r}")
    if metrics["brdf"] != brdf:
        raise RunFolderError(f"{path}: brdf '{metrics['brdf']}' but params.npz holds '{brdf}': files of two runs")
    return metrics


def load_run(folder) -> RunResult:
    """Read a run's output folder (python -m torchrefl.train ... output.dir=FOLDER); RunFolderError naming the
    file and what was expected when the run is incomplete (no valid completeness marker, a recorded file missing)
    or a file is damaged or changed; files the run did not write are ignored (RunResult.unrecorded)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RunFolderError(f"{folder}: run folder missing (expected the output.dir of a torchrefl.train run)")
    params_path = folder / PARAMS
    if not params_path.is_file():
        raise RunFolderError(f"{params_path}: missing (a run that finished writes it; was the run interrupted?)")
    marker = verify_run_folder(folder, hashed=(PARAMS, METRICS))
    p = _read_params(params_path)
    brdf = brdf_mod.check_brdf_name(str(p["brdf"]), f"{params_path}: brdf")
    diffuse, minnaert_k = _diffuse_part(p, params_path)
    metrics = _read_metrics(folder / METRICS, brdf)
    config = _read_mapping(folder / CONFIG, yaml.safe_load, "YAML")
    optional = lambda k: p[k] if k in p else None
    return RunResult(
        folder=folder,
        pd=p["pd"],
        ps=p["ps"],
        sigma=p["sigma"],
        mask=p["mask"],
        positions=p["positions"],
        normals=p["normals"],
        kappa=p["kappa"],
        brdf=brdf,
        units=str(p.get("units", "")),
        coverage=optional("coverage"),
        n_diffuse=optional("n_diffuse"),
        n_specular=optional("n_specular"),
        mesh=str(p["mesh"]) if "mesh" in p else None,
        **_uncertainty(p, params_path),
        metrics=metrics,
        config=config,
        diffuse=diffuse,
        minnaert_k=minnaert_k,
        unrecorded=tuple(unrecorded_files(folder, marker)),
    )
