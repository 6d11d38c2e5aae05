"""Typed configuration: dataclasses with a default and a one-line doc for every field.

Loading is strict: an unknown or misspelt key is a ConfigError that names the file,
the dotted key and the nearest valid key; a value of the wrong type or outside its
choices is a ConfigError naming the key and what was expected. Dotted overrides
(`output.dir=/tmp/x fit.holdout=[5,11,17]`) are parsed as YAML values and checked
the same way. The resolved config is written next to the outputs.

This module holds the schema (the dataclasses) and the entry points (load_config, to_dict,
dump_config, describe, resolve_path); the checking and applying machinery is in
torchrefl.config_loading (parse_override and read_yaml_mapping are importable from here too).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import yaml

from torchrefl.config_bundle import bundled_folder, config_path
from torchrefl.config_fields import opt
from torchrefl.config_loading import (
    PATH_KEYS,
    _apply,
    _field_types,
    _is_section,
    _nest,
    _validate,
    override_where,
    parse_override,
    read_yaml_mapping,
    yaml_value,
)
from torchrefl.config_selection import LightGridConfig, SelectionConfig, WorldLightsConfig  # noqa: F401 (re-exported)
from torchrefl.errors import ConfigError

PI = math.pi


@dataclass
class SyntheticConfig:
    """A synthetic object scanned by the seed's cylindrical rig (capture.kind: synthetic_cylindrical)."""

    object: str = opt(
        "ellipsoid",
        "synthetic object: ellipsoid, sphere, blob (analytic), or object_e, object_e_glossy, fold (non-uniform "
        "glossy), bowl, vase (meshes with interreflection)",
        choices=("ellipsoid", "sphere", "blob", "object_e", "object_e_glossy", "fold", "bowl", "vase"),
    )
    size_mm: list = opt([62.0, 95.0, 50.0], "semi-axes (x, y, z) of the object in mm (sphere uses the first)")
    materials: str = opt("regions", "ground-truth material layout", choices=("regions", "uniform"))
    brdf: str = opt(
        "torrance_sparrow",
        "BRDF used to render the synthetic images",
        choices=("torrance_sparrow", "ward", "ward_normalised"),
    )
    minnaert_k: float = opt(
        1.0,
        "Minnaert exponent k of the rendered diffuse part, Pd/pi (cos_l cos_v)^(k-1) (1 = Lambert; objects without "
        "interreflection only)",
        low=0.5,
        high=2.0,
    )
    columns: int = opt(512, "texels around (scan angles); the seed: 512", low=8)
    rows: int = opt(450, "texels along the axis (scan heights); the seed: 450", low=8)
    angle_step_deg: float = opt(0.7, "scan angle step in degrees; the seed: 0.7", low=0.0)
    height_step_mm: float = opt(0.56, "scan height step in mm; the seed: 0.56", low=0.0)
    camera_distance_mm: float = opt(300.0, "radial distance of the virtual camera from the axis, mm", low=0.0)
    light_intensity: float = opt(60000.0, "radiant intensity Y of the light (sensor full range x mm^2)", low=0.0)
    supersample: int = opt(3, "sub-samples per texel side used to render textures (finer than the fitter)", low=1)
    mesh_subdivisions: int = opt(6, "icosphere subdivisions of the object mesh (the truth geometry)", low=1)
    noise_dn: float = opt(0.3, "Gaussian sensor noise, in 8-bit digital numbers", low=0.0)
    noise_seed: Optional[int] = opt(
        None, "seed of the texture images' sensor noise (null = the run's seed; another value: a new draw, same scene)"
    )
    range_noise_mm: float = opt(0.0, "Gaussian range noise in mm", low=0.0)
    range_bits: Optional[int] = opt(
        None, "quantise the range image to this many bits (the seed's scanner: 8); null = no quantisation"
    )
    texture_bits: int = opt(8, "bit depth of the texture images (the seed: 8)", choices=(8, 16))
    indirect_samples: int = opt(
        0,
        "interreflection paths per visible sub-sample (Monte Carlo path tracing with Embree; 0 = direct light only)",
        low=0,
    )


@dataclass
class MeshViewsConfig:
    """A synthetic mesh_views scene (capture.kind: synthetic_mesh_views; torchrefl.synthetic.mesh_views)."""

    object: str = opt(
        "ellipsoid",
        "the object: ellipsoid (convex, with UVs), ellipsoid_no_uv (written without UVs), bowl (a deep concavity)",
        choices=("ellipsoid", "ellipsoid_no_uv", "bowl"),
    )
    width: int = opt(320, "image width, px", low=8)
    height: int = opt(240, "image height, px", low=8)
    focal_px: float = opt(520.0, "focal length, px", low=1.0)
    camera_distance_mm: float = opt(300.0, "distance of the cameras from the object's centre, mm", low=1.0)
    camera_elevations_deg: Optional[list] = opt(None, "one camera ring per elevation, deg; null = the object's")
    cameras_per_ring: int = opt(5, "cameras per ring, evenly spaced in azimuth", low=1)
    light_distance_mm: float = opt(350.0, "distance of the point lights from the object's centre, mm", low=1.0)
    lights_deg: Optional[list] = opt(
        None, "point lights as [azimuth, elevation] about the centre, deg; null = the object's"
    )
    lights_per_view: int = opt(2, "lights paired with each camera (the closest to it in direction)", low=1)
    light_intensity: list = opt([60000.0] * 3, "RGB radiant intensity Y of every light (full range x mm^2 per kappa)")
    exposures: list = opt([1.0], "exposure factors of the images, cycled over the images in order")
    supersample: int = opt(2, "sub-pixel rays per pixel side", low=1)
    noise_dn: float = opt(0.3, "Gaussian sensor noise, 8-bit digital numbers", low=0.0)
    indirect_samples: int = opt(
        16, "interreflection paths per sub-sample (concave objects only; 0 = direct only)", low=0
    )
    brdf: str = opt("torrance_sparrow", "BRDF of the rendering", ("torrance_sparrow", "ward", "ward_normalised"))


@dataclass
class CaptureConfig:
    """Where the photographs and geometry come from."""

    kind: str = opt(
        "synthetic_cylindrical",
        "capture kind",
        choices=(
            "synthetic_cylindrical",
            "cylindrical_scan",
            "photometric_stereo",
            "mesh_views",
            "synthetic_mesh_views",
        ),
    )
    path: str = opt(
        "",
        "capture folder (relative to the config file; on the command line, to the current folder); unused for "
        "synthetic",
    )
    saturation_level: float = opt(
        0.995, "fraction of full range at or above which a channel is saturated", low=0.0, high=1.0
    )
    kappa: list = opt([PI, PI, PI], "camera calibration gain per channel (i = kappa * L_o); pi reduces to eq. 2.9")
    light_subset: Optional[list] = opt(None, "indices of the lights to load (null = all; mesh_views: of the images)")
    noise_dn: Optional[float] = opt(
        None,
        "the camera's sensor noise std per channel, 8-bit DN, for the parameters' uncertainty (null = estimated from "
        "the fit's residuals)",
        low=0.0,
    )
    texture_size: int = opt(
        256, "mesh_views: side of the texel atlas, texels (the parameter maps are texture_size x texture_size)", low=16
    )


@dataclass
class GeometryConfig:
    """Range-image preprocessing (dissertation 2.3)."""

    median_size: Optional[int] = opt(
        None,
        "range median filter window (odd; 1 = none); null = auto: 5 on a noisy range image, none on a clean one",
        low=1,
    )
    fit_window: int = opt(5, "Yokoya-Levine quadratic fit window (odd)", low=3)
    shadow_offset_mm: float = opt(0.05, "origin offset along the normal for shadow rays, mm", low=0.0)
    edge_width: int = opt(
        1,
        "texels within this many texels of the scanned surface's boundary (mixed pixels) are not fitted (0 = use them)",
        low=0,
    )
    crease_angle_deg: Optional[float] = opt(
        None,
        "texels on a crease sharper than this many degrees (mixed pixels) are not fitted; null = use them",
        low=1.0,
        high=179.0,
    )


@dataclass
class ReflectanceConfig:
    """The reflectance model and the observation classes (dissertation 2.4, 3.2)."""

    brdf: str = opt(
        "torrance_sparrow", "specular lobe", choices=("torrance_sparrow", "ward", "ward_normalised", "lambertian")
    )
    diffuse: str = opt(
        "lambert",
        "diffuse part: lambert (Pd/pi, eq. 2.9) or minnaert (Pd/pi (cos_l cos_v)^(k-1), darker than Lambert towards "
        "grazing for k > 1; local transport only)",
        choices=("lambert", "minnaert"),
    )
    minnaert_k: Optional[float] = opt(
        None,
        "Minnaert exponent k with diffuse: minnaert; null = fitted on the diffuse-only (T_diff) observations, one k "
        "for the object",
        low=0.5,
        high=2.0,
    )
    ps_channels: int = opt(3, "specular reflectance channels: 3 = RGB, 1 = grey", choices=(1, 3))
    theta_diffuse_deg: float = opt(
        60.0, "theta_th1: half-angle above which an observation is diffuse only (eq. 2.20)", low=0.0, high=90.0
    )
    theta_specular_deg: float = opt(
        20.0, "theta_th2: half-angle at or below which specular is strong (eq. 2.21)", low=0.0, high=90.0
    )
    sigma_min: float = opt(0.01, "lower bound of the roughness sigma (radians)", low=1e-4)
    sigma_max: float = opt(0.6, "upper bound of the roughness sigma (radians)", low=1e-3)
    ps_max: float = opt(
        4.0,
        "upper bound of Ps (kappa = pi units: 1 = a specular peak as bright as white paper); stops tiny-sigma, huge-Ps "
        "fits of faint tails",
        low=1e-3,
    )
    min_cos_view: float = opt(
        0.05, "observations with n.v at or below this are not used (grazing view)", low=0.0, high=1.0
    )
    min_cos_light: float = opt(
        0.02, "observations with n.l at or below this are not used (grazing light)", low=0.0, high=1.0
    )


@dataclass
class FitConfig:
    """Fitting of the texel parameter tensors."""

    model: str = opt(
        "local",
        "transport level: local (Method I), radiosity (II), photon (III) or auto (the cheapest that explains the data)",
        choices=("local", "radiosity", "photon", "auto"),
    )
    noise_floor_dn: float = opt(0.5, "auto: interreflection below this many 8-bit DN is not modelled", low=0.0)
    optimizer: str = opt(
        "lm",
        "refinement optimiser: lm (Levenberg-Marquardt per texel; lbfgs where texels are coupled), lbfgs, adam, none",
        choices=("lm", "lbfgs", "adam", "none"),
    )
    iterations: int = opt(
        60,
        "refinement steps per refit: at most this many LM steps (they stop on convergence), LBFGS or Adam steps",
        low=0,
    )
    learning_rate: float = opt(0.05, "Adam learning rate (LBFGS uses a strong-Wolfe line search)", low=0.0)
    loss: str = opt("huber", "robust loss on 8-bit residuals", choices=("l2", "huber", "cauchy"))
    loss_scale_8bit: float = opt(3.0, "robust loss scale, in 8-bit digital numbers", low=1e-6)
    holdout: list = opt([], "light indices excluded from fitting and evaluated afterwards")
    interpolation_window: int = opt(5, "W: window for interpolating undetermined texels (W x W)", low=1)
    sigma_search: int = opt(
        32,
        "grid values of the variable-projection sigma search, narrowed between them, that can replace the closed-form "
        "start (0 = off)",
        low=0,
    )
    specular: str = opt(
        "texel",
        "Ps, sigma per texel (texel), one lobe for the whole object (shared), or per texel pulled towards the shared "
        "lobe (pooled)",
        choices=("texel", "shared", "pooled"),
    )
    pooling: float = opt(0.01, "weight of the pull towards the shared lobe when fit.specular is pooled", low=0.0)
    smoothness: float = opt(
        0.0, "weight of a neighbour-difference prior on log Ps and sigma (0 = independent texels)", low=0.0
    )
    prior_weight: float = opt(
        0.1, "weight pulling texels without specular evidence towards their interpolated Ps, sigma", low=0.0
    )
    init_from: Optional[str] = opt(
        None,
        "run folder whose params.npz starts the fit where it has an estimate (a warm start; same texel grid); "
        "null = the closed-form start",
    )


@dataclass
class RadiosityConfig:
    """The radiosity level (Method II): patches, form factors, the linear solve."""

    patch_size: int = opt(
        2, "patch side in texels (patches are patch_size x patch_size texel blocks; 1 = one texel per patch)", low=1
    )
    hemisphere_samples: int = opt(2048, "cosine-weighted hemisphere rays per patch for the form factors", low=1)
    solve_samples: Optional[int] = opt(
        256,
        "hemisphere rays per patch of a cheaper second form-factor set used only by the radiosity solve (null = one "
        "set)",
        low=1,
    )
    light_maps: int = opt(
        8,
        "emitter maps per light for lights that move with the scan, interpolated cubically per texel (1 = none)",
        low=1,
    )


@dataclass
class PhotonConfig:
    """The photon level (Method III): photon tracing, the indirect-light cache, the outer loop."""

    photons_per_light: int = opt(
        1_600_000, "photons traced per light and cache refresh (shared by its light maps)", low=1
    )
    light_maps: int = opt(
        8,
        "photon maps per light when the lights move with the scan (co-rotating rig); texels interpolate cubically "
        "between the four nearest",
        low=1,
    )
    outer_iterations: int = opt(
        5,
        "th2: at most this many cache refreshes followed by a refit (fewer once Pd moves less than its std; the best "
        "parameters by image difference are kept)",
        low=0,
    )
    schedule: str = opt(
        "joint",
        "joint: refit Pd, Ps, sigma together; seed: (a) Pd on T_diff then (b) Ps, sigma on T_spec and T_none, as the "
        "dissertation",
        choices=("joint", "seed"),
    )
    damping: float = opt(
        0.0,
        "fraction of the previous refresh's Pd that Pd keeps after each photon refit (under-relaxation; 0 = none)",
        low=0.0,
        high=0.95,
    )
    smoothing: Optional[float] = opt(
        None,
        "std in texels of the Gaussian that smooths the cached indirect irradiance over the texel grid (0 = each "
        "texel's own photons); null = auto: the kernel holds about 10,000 of a light's photons",
        low=0.0,
    )
    diffuse_paths: str = opt(
        "radiosity",
        "source of the all-diffuse paths' indirect light: photons, or radiosity (the radiosity solution, noise-free)",
        choices=("photons", "radiosity"),
    )
    specular_smoothing: Optional[float] = opt(
        None,
        "std in texels of the Gaussian (radius round(std)) that spreads each photon's specular entry (0 = per "
        "texel); null = auto: the kernel holds about 5,000 of a light's photons",
        low=0.0,
    )
    specular_gather: int = opt(
        64,
        "with diffuse_paths radiosity: lobe directions per texel that gather the specular reflection of diffuse light "
        "(0 = off; unused with photons)",
        low=0,
    )


@dataclass
class OutputConfig:
    """What is written and where."""

    dir: str = opt("outputs/default", "output folder (relative paths are relative to the current directory)")
    map_lights: int = opt(3, "number of lights for observed / re-rendered / difference PNGs", low=0)
    progress: bool = opt(True, "show progress bars")
    export: bool = opt(True, "write export/: OBJ + MTL, glTF .glb, 16-bit PNG and OpenEXR maps (docs/exports.md)")


@dataclass
class Config:
    """A torchrefl run."""

    seed: int = opt(0, "seed of every random number (noise, sampling)")
    device: str = opt("cpu", "torch device for the fit", choices=("cpu", "cuda", "auto"))
    dtype: str = opt("float32", "floating point precision of the fit", choices=("float32", "float64"))
    threads: int = opt(2, "CPU threads for Embree and torch", low=1)
    capture: CaptureConfig = field(default_factory=CaptureConfig, metadata={"doc": "capture"})
    synthetic: SyntheticConfig = field(default_factory=SyntheticConfig, metadata={"doc": "synthetic scene"})
    views: MeshViewsConfig = field(
        default_factory=MeshViewsConfig,
        metadata={"doc": "synthetic mesh_views scene (capture.kind synthetic_mesh_views)"},
    )
    geometry: GeometryConfig = field(default_factory=GeometryConfig, metadata={"doc": "geometry"})
    selection: SelectionConfig = field(default_factory=SelectionConfig, metadata={"doc": "light selection"})
    reflectance: ReflectanceConfig = field(default_factory=ReflectanceConfig, metadata={"doc": "reflectance model"})
    fit: FitConfig = field(default_factory=FitConfig, metadata={"doc": "fit"})
    radiosity: RadiosityConfig = field(default_factory=RadiosityConfig, metadata={"doc": "radiosity level"})
    photon: PhotonConfig = field(default_factory=PhotonConfig, metadata={"doc": "photon level"})
    output: OutputConfig = field(default_factory=OutputConfig, metadata={"doc": "outputs"})
    config_dir: str = field(
        default=".", metadata={"doc": "(set by the loader) folder of the config file", "internal": True}
    )

    @property
    def torch_dtype(self):
        """The torch dtype named by `dtype`."""
        import torch

        return torch.float64 if self.dtype == "float64" else torch.float32


# ---------------------------------------------------------------------------- entry points


def load_config(path: Optional[str | Path] = None, overrides: list[str] = ()) -> Config:
    """Load a YAML config strictly, apply dotted overrides, validate; returns Config. `path` is a YAML file, or the
    name of a bundled config (`default`; torchrefl.config_bundle) when no file of that name exists."""
    cfg = Config()
    sources: dict[str, str] = {}
    default_where = str(path) if path is not None else "config"
    if path is not None:
        path = config_path(path)
        data = read_yaml_mapping(path, ConfigError, "config file")
        _apply(cfg, data, "", str(path), sources)
        cfg.config_dir = str(path.resolve().parent)
    for text in overrides:
        key, value = parse_override(text)
        if key in PATH_KEYS and isinstance(value, str) and value and not Path(value).is_absolute():
            value = str(Path.cwd() / value)  # command-line paths are relative to the current folder
        _apply(cfg, _nest(key, value), "", override_where(text), sources)
    _validate(cfg, lambda key: sources.get(key, default_where))
    return cfg


def to_dict(cfg) -> dict:
    """Plain dict of a config (for YAML dumps)."""
    out = {}
    for f in dataclasses.fields(cfg):
        if f.metadata.get("internal"):
            continue
        value = getattr(cfg, f.name)
        out[f.name] = to_dict(value) if dataclasses.is_dataclass(value) else value
    return out


def run_config_text(cfg: Config) -> str:
    """The YAML of a run folder's config.yaml: the config with its relative paths (PATH_KEYS, fit.init_from) made
    absolute against the config file's folder, so that the run folder names the same data wherever it is read from."""
    data = to_dict(cfg)
    for key in (*PATH_KEYS, "fit.init_from"):
        *sections, name = key.split(".")
        where = data
        for section in sections:
            where = where[section]
        value = where[name]
        if isinstance(value, str) and value and not Path(value).is_absolute():
            where[name] = str(Path(cfg.config_dir) / value)
    return yaml.safe_dump(data, sort_keys=False)


def dump_config(cfg: Config, path: str | Path) -> None:
    """Write the resolved config as YAML."""
    Path(path).write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))


def describe(cls=Config, prefix: str = "") -> list[str]:
    """One line per option: dotted key, default, choices, doc (for --help), values written as on the command line
    (null, true, [1, 2])."""
    lines = []
    inst = cls()
    for name, (f, tp) in _field_types(cls).items():
        if f.metadata.get("internal"):
            continue
        if _is_section(tp):
            lines.append(f"{prefix}{name}:  ({f.metadata.get('doc', '')})")
            lines.extend(describe(tp, prefix + name + "."))
            continue
        meta = f.metadata
        choices = f" {{{', '.join(map(yaml_value, meta['choices']))}}}" if meta.get("choices") else ""
        default = yaml_value(getattr(inst, name))
        lines.append(f"  {prefix}{name} = {default}{choices}  -- {meta.get('doc', '')}")
    return lines


def resolve_path(cfg: Config, value: str, key: str = "capture.path") -> Path:
    """A path from the config, relative to the config file's folder. A relative path of a bundled config that does
    not exist is a ConfigError: it points into a repository checkout (the bundled configs' folder) and is to be given
    on the command line instead."""
    p = Path(value)
    if p.is_absolute():
        return p
    resolved = Path(cfg.config_dir) / p
    if not resolved.exists() and Path(cfg.config_dir) == bundled_folder():
        raise ConfigError(
            f"{resolved}: key '{key}' = '{value}' of a bundled config is relative to the bundled configs' folder and "
            f"does not exist there; give it on the command line, e.g. {key}=/path/to/data (relative to the current "
            "folder)"
        )
    return resolved
