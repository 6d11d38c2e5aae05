"""Shared test scene: texels on a gently curved patch lit by point lights, observations from
the exact local model (so closed forms and fits can be checked against known parameters)."""

import json
import math
import os
import sys
from pathlib import Path

if os.environ.get("PYTEST_XDIST_WORKER"):
    # set before numpy and torch load: each xdist worker has about a core, so BLAS pools of one thread, and OpenMP
    # threads that sleep instead of spinning while the other worker holds the core
    for name, value in (("OPENBLAS_NUM_THREADS", "1"), ("MKL_NUM_THREADS", "1"), ("OMP_WAIT_POLICY", "PASSIVE")):
        os.environ.setdefault(name, value)

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from torchrefl.core.observations import Observations  # noqa: E402


def point_light_observations(normals, positions, light_positions, camera, intensity=1.0e5, dtype=torch.float64):
    """Observations (no intensities yet: zeros) for point lights (P, 3) and a pinhole camera position (3,)."""
    x = torch.as_tensor(positions, dtype=dtype)
    n = torch.as_tensor(normals, dtype=dtype)
    L = torch.as_tensor(light_positions, dtype=dtype)
    to_l = L[:, None, :] - x[None]
    dist = to_l.norm(dim=-1)
    l = to_l / dist[..., None]
    v = torch.as_tensor(camera, dtype=dtype) - x
    v = v / v.norm(dim=-1, keepdim=True)
    P, T = l.shape[:2]
    valid = ((n[None] * l).sum(-1) > 0) & ((n * v).sum(-1) > 0)[None]
    return Observations(
        intensity=torch.zeros(P, T, 3, dtype=dtype),
        valid=valid,
        saturated=torch.zeros(P, T, dtype=torch.bool),
        shadowed=torch.zeros(P, T, dtype=torch.bool),
        light_dir=l,
        falloff=1.0 / dist**2,
        light_intensity=torch.full((P, 3), float(intensity), dtype=dtype),
        view_dir=v,
        kappa=torch.full((3,), math.pi, dtype=dtype),
        light_positions=L,
    )


def dome_scene(T=400, seed=0, dtype=torch.float64):
    """Texels on a shallow spherical cap (normals within ~25 deg of +z), oblique camera, a 9 x 9 grid of low
    lights above the cap. Returns normals (T, 3), positions (T, 3), lights (81, 3), camera (3,)."""
    rng = np.random.default_rng(seed)
    R = 200.0
    xy = rng.uniform(-80, 80, size=(T, 2))
    z = np.sqrt(R**2 - (xy**2).sum(1)) - R
    pos = np.column_stack([xy, z])
    nrm = pos - np.array([0.0, 0.0, -R])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    g = np.linspace(-450, 450, 9)
    gx, gy = np.meshgrid(g, g)
    lights = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, 100.0)])
    camera = np.array([400.0, 0.0, 250.0])
    return nrm, pos, lights, camera


@pytest.fixture
def dome():
    return dome_scene()


def fold_surface(H=24, W=48, L=60.0, dtype=torch.float64):
    """A concave 90 degree fold as a texel grid: columns run across the floor (z = 0, x < 0, normal +z)
    and up the wall (x = 0, z > 0, normal -x), rows along the fold (y). Texel centres sit half a texel
    off the fold line. The mesh is the grid's triangulation. Columns W/2 - 1 and W/2 touch the fold."""
    from torchrefl.core.surface import Surface
    from torchrefl.geometry.range_mesh import grid_triangulation, texel_areas

    u = (np.arange(W) + 0.5) / W * 2 * L - L
    y = (np.arange(H) + 0.5) / H * L - L / 2
    U, Y = np.meshgrid(u, y)
    pts = np.stack([np.where(U < 0, U, 0.0), Y, np.where(U < 0, 0.0, U)], -1)
    nrm = np.where((U < 0)[..., None], np.array([0, 0, 1.0]), np.array([-1.0, 0, 0]))
    valid = np.ones((H, W), bool)
    verts, faces = grid_triangulation(pts, valid)
    areas = texel_areas(pts, valid)
    return Surface(
        (H, W),
        torch.arange(H * W),
        torch.tensor(pts.reshape(-1, 3), dtype=dtype),
        torch.tensor(nrm.reshape(-1, 3), dtype=dtype),
        torch.tensor(areas.reshape(-1), dtype=dtype),
        verts,
        faces,
        source="fold_surface",
    )


def noisy_glossy_scene(T=300, seed=0, outliers=0, noise=0.5):
    """A dome of T texels with random non-uniform Pd, Ps, sigma under every other dome light, imaged with
    Gaussian noise of `noise` DN and 8-bit quantisation (noise 0: the exact images), `outliers` pixels set to
    white; observations that near saturation are not valid. Returns obs, local terms, (pd, ps, sigma)."""
    from torchrefl.transport.local import local_terms, predict

    nrm, pos, lights, cam = dome_scene(T=T, seed=seed)
    obs = point_light_observations(nrm, pos, lights[::2], cam, intensity=2.0e4)
    g = torch.Generator().manual_seed(seed)
    pd = 0.2 + 0.5 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    ps = 0.1 + 0.3 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    sigma = 0.08 + 0.15 * torch.rand(T, generator=g, dtype=torch.float64)
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    clean = predict(terms, pd, ps, sigma)
    images = clean
    if noise:
        images = clean + torch.randn(clean.shape, generator=g, dtype=torch.float64) * (noise / 255)
        images = (images * 255).round().clamp(0, 255) / 255
    if outliers:
        idx = torch.randint(0, images.numel(), (outliers,), generator=g)
        images.view(-1)[idx] = 1.0
    obs.intensity = images
    obs.valid &= clean.max(-1).values < 0.99
    return obs, terms, (pd, ps, sigma)


def atlas_cube(side: int = 8, texture_size: int = 32, gap: int = 1):
    """The cube of tests/geometry/atlas_meshes.py (side x side texels of 1 mm per face, charts `gap` texels apart
    in a 3 x 2 atlas layout, turned and mirrored) as an AtlasGeometry (its surface carries AtlasNeighbours)."""
    sys.path.insert(0, str(Path(__file__).parent / "geometry"))
    from atlas_meshes import cube_atlas

    from torchrefl.geometry.atlas_surface import atlas_geometry

    return atlas_geometry(cube_atlas(side_texels=side, texture_size=texture_size, gap=gap), texture_size)


def atlas_cylinder(texture_size: int = 32):
    """The open cylinder of tests/geometry/atlas_meshes.py (radius 10 mm, height 20 mm; one chart whose first and
    last texel columns meet across a UV seam) as an AtlasGeometry."""
    sys.path.insert(0, str(Path(__file__).parent / "geometry"))
    from atlas_meshes import open_cylinder

    from torchrefl.geometry.atlas_surface import atlas_geometry

    return atlas_geometry(open_cylinder(10.0, 20.0), texture_size)


def write_grid_run(folder, positions, normals, *, mask=None, pd=0.5, ps=0.2, sigma=0.2, units="mm", **extra):
    """A complete run folder (params.npz, metrics.json, config.yaml, the completeness marker) whose texel grid has
    the given positions, normals (H, W, 3) and uniform or per-texel pd, ps (RGB), sigma; mask: texels with an
    estimate (default: all with a unit normal); extra: more params.npz keys (e.g. mesh). Returns the params."""
    from torchrefl.report.run_marker import write_marker

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    H, W = positions.shape[:2]
    grid = lambda v, c: np.broadcast_to(np.asarray(v, dtype=np.float64), (H, W, c) if c else (H, W)).copy()
    mask = (np.linalg.norm(normals, axis=-1) > 0.5) if mask is None else mask
    params = dict(
        pd=grid(pd, 3),
        ps=grid(ps, 3),
        sigma=grid(sigma, 0),
        mask=mask,
        brdf=np.array("torrance_sparrow"),
        positions=positions,
        normals=normals,
        kappa=np.full(3, math.pi),
        units=np.array(units),
        **extra,
    )
    np.savez_compressed(folder / "params.npz", **params)
    metrics = {
        "model": "local",
        "brdf": "torrance_sparrow",
        "texels": int(mask.sum()),
        "lights": 1,
        "timing_s": {"total": 1.0},
        "rerender": {},
    }
    (folder / "metrics.json").write_text(json.dumps(metrics))
    (folder / "config.yaml").write_text("geometry:\n  shadow_offset_mm: 0.05\n")
    write_marker(folder)
    return params


def atlas_room(side: int = 8, texture_size: int = 32, shift=(0.37, -0.21), gap: int = 1):
    """The inside of the cube of tests/geometry/atlas_meshes.py (side x side texels of 1 mm per face; winding
    reversed, so the normals face in) with its UVs moved by `shift` texels, so that texel centres sit off the chart
    borders and the border cells are partly gutter (gap 0: partly the next chart's): a closed room whose every wall
    meets four chart seams. Chart k is the cube's face k, mesh faces 2k and 2k + 1."""
    sys.path.insert(0, str(Path(__file__).parent / "geometry"))
    from dataclasses import replace

    from atlas_meshes import cube_atlas

    from torchrefl.geometry.atlas_surface import atlas_geometry

    mesh = cube_atlas(side_texels=side, texture_size=texture_size, gap=gap)
    uvs = mesh.uvs + np.asarray(shift, dtype=np.float64) / texture_size
    return atlas_geometry(replace(mesh, faces=mesh.faces[:, ::-1].copy(), uvs=uvs[:, ::-1].copy()), texture_size)


@pytest.fixture
def write_json(tmp_path):
    """write_json(name, doc) -> the path of tmp_path / name holding doc as JSON (a str is written as it is)."""

    def write(name: str, doc):
        path = tmp_path / name
        path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
        return path

    return write


def load_script(name: str):
    """scripts/NAME.py imported as a module (registered in sys.modules: dataclasses look their module up there)."""
    import importlib.util

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location(name, root / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def tiny_fold_run(tmp_path_factory):
    """The tiny glossy fold of scripts/tiny_mode.py fitted with the photon level: the run folder (its capture in
    capture/), shared by the scripts' tests that analyse a finished run."""
    return load_script("tiny_mode").tiny_run(tmp_path_factory.mktemp("tiny_fold") / "run")


@pytest.fixture(scope="session")
def tiny_views_run(tmp_path_factory):
    """The tiny synthetic mesh_views capture of scripts/tiny_mode.py (TINY_VIEWS: a 16 x 16 atlas, 4 cameras, 8
    images, image 1 held out) fitted at the local level: the run folder (its capture in capture/), shared by the
    tests that read a finished mesh_views run."""
    script = load_script("tiny_mode")
    return script.tiny_run(
        tmp_path_factory.mktemp("tiny_views") / "run", script.ROOT / "configs" / "mesh_views.yaml", "local"
    )


#: the doc-command test (tests/docs/test_doc_commands.py) whose skipped blocks are listed at the end of a run
DOC_TEST = "test_doc_block_runs_as_written"


def pytest_terminal_summary(terminalreporter):
    """The doc blocks that were not run, each with its marker's reason, listed at the end of every run that had some
    (a conftest.py in a test folder would shadow this module for `from conftest import ...`)."""
    skipped = [r for r in terminalreporter.stats.get("skipped", []) if DOC_TEST in r.nodeid]
    if not skipped:
        return
    terminalreporter.section("doc blocks not run (their markers in the markdown)")
    for report in skipped:
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        terminalreporter.write_line(reason.removeprefix("Skipped: "))


#: the quick scene at 24 x 32 texels under the 6 candidates of a 3 x 2 light grid, one torch thread: a run in a
#: second or two (tests/fit/test_warm_start.py, tests/rig/test_adaptive.py)
TINY_QUICK_SCENE = (
    "synthetic.columns=32",
    "synthetic.rows=24",
    "synthetic.angle_step_deg=11.25",
    "synthetic.height_step_mm=6.0",
    "synthetic.supersample=1",
    "synthetic.mesh_subdivisions=3",
    "selection.grid.columns=3",
    "selection.grid.rows=2",
    "threads=1",
)


#: the lights and camera of the photon_traced fixture (tests/transport: the photon cache and its build)
CACHE_LIGHTS = np.array([[-40.0, 5.0, 50.0], [-20.0, -10.0, 70.0]])
CACHE_CAMERA = np.array([-150.0, 0.0, 150.0])


@pytest.fixture(scope="module")
def photon_traced():
    """A fold of 8 x 16 texels under CACHE_LIGHTS (4 light maps each), Torrance-Sparrow at random Pd, Ps, sigma, and
    its trace: (surface, observations, PhotonTracer, LightSources, PhotonHits, pd, ps, sigma)."""
    from torchrefl.transport.light_maps import light_sources

    s = fold_surface(8, 16)
    T = s.num_texels
    obs = point_light_observations(s.normals, s.positions, CACHE_LIGHTS, CACHE_CAMERA, intensity=1e4)
    pt = photon_tracer(s, "torrance_sparrow")
    src = light_sources(s, obs, 4)
    g = torch.Generator().manual_seed(0)
    pd = 0.2 + 0.6 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    ps = 0.1 + 0.5 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    sigma = 0.05 + 0.3 * torch.rand(T, generator=g, dtype=torch.float64)
    return s, obs, pt, src, trace_photons(pt, src, pd, ps, sigma, seed=0), pd, ps, sigma


def trace_photons(pt, src, pd, ps, sigma, seed):
    """3,000 photons per light map through the texels' materials."""
    from torchrefl.transport.photon_material import TexelMaterial

    material = TexelMaterial.from_tensors(pd, ps, sigma)
    return pt.trace(src.positions.reshape(-1, 3), np.repeat(src.intensity, src.num_maps, 0), 3000, material, seed=seed)


def photon_cache_of(
    photon_traced,
    theta_bin,
    sigma_max=10.0,
    linear=False,
    smoothing=0.0,
    smoothing_normal=0.0,
    specular_smoothing=0.0,
    bin_per_sigma=0.0,
    cache_sigma=None,
):
    """The cache of photon_traced's hits with these options, smoothed (when asked) over the normals-guided grid."""
    s, *_, pd, ps, sigma = photon_traced
    return build_photon_cache(
        photon_traced,
        cache_sigma=cache_sigma,
        sigma_max=sigma_max,
        theta_bin=theta_bin,
        bin_per_sigma=bin_per_sigma,
        emitter_pd=pd.numpy() if linear else None,
        smoothing=smoothing,
        grid=(s.neighbours, s.normals),
        smoothing_normal=smoothing_normal,
        specular_smoothing=specular_smoothing,
    )


def build_photon_cache(photon_traced, hits=None, cache_sigma=None, sigma_max=10.0, **options):
    """build_cache of photon_traced's hits (or these hits), every observation kept, the specular entries pruned at
    cache_sigma (T,) (1 everywhere when None); options: build_cache's keywords."""
    from torchrefl.transport.cache_build import build_cache

    s, obs, pt, src, traced_hits, *_ = photon_traced
    keep = torch.ones(obs.valid.shape, dtype=torch.bool)
    cache_sigma = np.full(s.num_texels, 1.0) if cache_sigma is None else cache_sigma
    hits = traced_hits if hits is None else hits
    return build_cache(
        hits, src, pt.areas, s.normals, obs.view_dir, keep, "torrance_sparrow", cache_sigma, sigma_max, 0.02, **options
    )


def photon_tracer(surface, brdf: str, **options):
    """A PhotonTracer over the surface's mesh (Embree's default threads), rays offset 1e-3; options: its keywords."""
    from torchrefl.core.rays import RayTracer
    from torchrefl.transport.photon_trace import PhotonTracer

    return PhotonTracer(
        RayTracer(surface.mesh_vertices, surface.mesh_faces),
        surface.texel_index.numpy(),
        surface.positions.numpy(),
        surface.normals.numpy(),
        brdf,
        offset=1e-3,
        **options,
    )
