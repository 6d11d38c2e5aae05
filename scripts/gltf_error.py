"""How far the exported glTF material is from the fitted model: re-render a run's capture lights both ways.

For each bundled config: fit it (or reuse its run folder), export the .glb (torchrefl's export), read the material
back from the file (tests/reference/gltf_brdf.py: pygltflib, Pillow and the glTF 2.0 BRDF written from the
specification, sharing no code with torchrefl) and render every light of the capture (local transport: direct
light, the capture's own shadow mask) with the fitted model (torchrefl.transport.local.render_reference) and with
the glTF material; the table gives the mean |difference| in 8-bit DN over the lit, seen, estimated observations
(both renders clipped to the sensor's range), for the fitted conversion (the .glb torchrefl writes), for the
one-line formula (export_material: formula 'one_line') and, to show what glTF's diffuse darkening costs, the
fitted conversion with the base colour Pd / (1 - specular) (not written: the exported base colour is Pd); then
both conversions' over the observations near a highlight alone (the fitted model's specular part above NEAR_DN).

    python scripts/gltf_error.py --configs default quick mesh_views --work outputs/gltf_error
    python scripts/gltf_error.py --configs diligent_ball --ball /path/to/DiLiGenT/pmsData/ballPNG
    python scripts/gltf_error.py --tiny          # a 9 x 12 cap and 3 lights, no fit (tests/scripts runs it)

--reuse takes an existing run in WORK/NAME instead of fitting. --set KEY=VALUE (repeatable) is passed to every fit
(`python -m torchrefl.train NAME KEY=VALUE ...`), for configs whose full fit is too slow (e.g. `--set fit.model=local
synthetic.indirect_samples=16`); the table's note column names them. --out PAGE writes the table as markdown.
docs/results/exports.md has the numbers.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from reference.gltf_brdf import GlbMaterial, gltf_brdf  # noqa: E402

from torchrefl.capture.base import loader_for  # noqa: E402
from torchrefl.config import load_config  # noqa: E402
from torchrefl.core.observations import Observations  # noqa: E402
from torchrefl.geometry.range_mesh import grid_triangulation  # noqa: E402
from torchrefl.report.export_glb import write_glb  # noqa: E402
from torchrefl.report.export_maps import specular_scale, write_textures  # noqa: E402
from torchrefl.report.export_material import gltf_material  # noqa: E402
from torchrefl.report.export_mesh import scan_mesh  # noqa: E402
from torchrefl.report.run_marker import write_marker  # noqa: E402
from torchrefl.report.run_result import RunResult, load_run  # noqa: E402
from torchrefl.transport.local import light_scale, render_reference  # noqa: E402

CONFIGS = (
    "quick",
    "default",
    "mesh_views",
    "diligent_ball",
    "fold",
    "object_e_setup1",
    "object_e_setup2",
    "bowl",
    "mesh_views_concave",
    "concave",
)
SYNTHETIC = {"synthetic_cylindrical": "cylindrical_scan", "synthetic_mesh_views": "mesh_views"}
BALL_SHOWN = "/path/to/DiLiGenT/pmsData/ballPNG"
#: an observation is near a highlight where the fitted model's specular part exceeds this many 8-bit DN
NEAR_DN = 2.0


@dataclass
class Row:
    """One config's numbers (8-bit DN means over `count` observation channels)."""

    name: str
    texels: int
    lights: int
    count: int
    specular: float  # the median glTF specular strength s of the estimated texels (their diffuse is 1 - s too dark)
    fit_vs_photos: float | None  # the run's own metrics.json rerender mean |diff|
    fitted: float  # the written .glb vs the fitted model
    one_line: float
    compensated: float
    near_share: float = math.nan  # the share of the observations near a highlight (fitted specular > NEAR_DN)
    fitted_near: float = math.nan  # fitted / one_line over those observations alone
    one_line_near: float = math.nan
    note: str = ""


def capture_of(run: RunResult, ball: Path | None):
    """The capture the run fitted (synthetic kinds: the folder the run wrote, read by its loader)."""
    section = run.config.get("capture", {})
    kind = section.get("kind")
    over = ["output.progress=false"]
    if kind in SYNTHETIC:
        over += [f"capture.kind={SYNTHETIC[kind]}", f"capture.path={run.folder / 'capture'}"]
        kind = SYNTHETIC[kind]
    elif ball is not None:
        over += [f"capture.path={ball}"]
    cfg = load_config(run.folder / "config.yaml", over)
    return loader_for(kind).load(Path(cfg.capture.path), cfg, lambda msg: None)


def glb_of(run: RunResult, folder: Path, formula: str) -> Path:
    """A .glb of the run's estimate with the conversion `formula` (the run's mesh; a grid mesh for a run without
    one: photometric stereo), written by torchrefl's exporter."""
    folder.mkdir(parents=True, exist_ok=True)
    if formula == "fitted" and run.config.get("capture", {}).get("kind") != "photometric_stereo":
        return run.export(folder, formats=["glb"]).folder / "object.glb"
    verts, faces = grid_triangulation(run.positions, np.linalg.norm(run.normals, axis=-1) > 0.5)
    mesh = scan_mesh(run.positions, run.normals, faces, run.units)
    material = gltf_material(run.pd, run.ps, run.sigma, run.brdf, formula)
    textures = write_textures(folder / "textures", material, run.mask)
    write_glb(folder / "object.glb", mesh, textures, specular_scale(material, run.mask))
    return folder / "object.glb"


def render_gltf(params: dict, n, obs: Observations, base_scale=None) -> torch.Tensor:
    """(P, T, 3) the camera's values of the glTF material (params at the texels) under the capture's lights."""
    v = obs.view_dirs_full().double().numpy()
    l = obs.light_dir.double().numpy()
    base = params["base_color"] if base_scale is None else np.clip(params["base_color"] * base_scale[:, None], 0, 1)
    out = np.empty(l.shape)
    for p in range(len(l)):
        f = gltf_brdf(
            n, l[p], v[p], base, params["roughness"], params["metallic"], params["specular"], params["specular_color"]
        )
        out[p] = f * np.clip(np.sum(n * l[p], -1), 0, None)[:, None]
    return light_scale(obs).double() * torch.from_numpy(out)


def mean_dn(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float:
    return float(((a.clamp(0, 1) - b.clamp(0, 1)).abs() * 255.0)[mask].mean())


def compare(run: RunResult, obs: Observations, texel_index: np.ndarray, normals: np.ndarray, work: Path) -> dict:
    """The mean 8-bit differences of the three glTF renders from the fitted model's (module docstring)."""
    H, W = run.grid_shape
    rows, cols = np.divmod(np.asarray(texel_index), W)
    est = run.mask[rows, cols]
    n = normals / np.linalg.norm(normals, axis=-1, keepdims=True)
    t = lambda a: torch.from_numpy(np.asarray(a, dtype=np.float64))
    ps = run.ps[rows, cols]
    fitted = render_reference(
        run.brdf, t(n), _double(obs), t(run.pd[rows, cols]), t(ps), t(run.sigma[rows, cols]), run.minnaert_k
    )
    mask = obs.valid & torch.from_numpy(est)[None]
    diffuse = render_reference(
        run.brdf, t(n), _double(obs), t(run.pd[rows, cols]), t(0.0 * ps), t(run.sigma[rows, cols]), run.minnaert_k
    )
    near = mask & ((fitted - diffuse).amax(-1) * 255.0 > NEAR_DN)
    out = {"count": int(mask.sum()) * 3, "near_share": float(near.sum()) / max(int(mask.sum()), 1)}
    for formula in ("fitted", "one_line"):
        material = GlbMaterial(glb_of(run, work / formula, formula)).at_texels(rows, cols)
        rendered = render_gltf(material, n, _double(obs))
        out[formula] = mean_dn(rendered, fitted, mask)
        out[f"{formula}_near"] = mean_dn(rendered, fitted, near) if bool(near.any()) else math.nan
        if formula == "fitted":
            scale = 1.0 / np.maximum(1.0 - material["specular"], 1e-6)
            out["compensated"] = mean_dn(render_gltf(material, n, _double(obs), scale), fitted, mask)
            out["specular"] = float(np.median(material["specular"][est])) if est.any() else 0.0
    return out


def _double(obs: Observations) -> Observations:
    conv = {k: getattr(obs, k).double() for k in ("intensity", "light_dir", "falloff", "light_intensity", "kappa")}
    return replace(obs, view_dir=obs.view_dir.double(), **conv)


def run_config(name: str, work: Path, reuse: bool, ball: Path | None, overrides: tuple[str, ...] = ()) -> Row:
    """One config's row: fit it with `overrides` (or reuse WORK/NAME) and compare the renders."""
    out = work / name
    if name == "diligent_ball" and (ball is None or not ball.is_dir()):
        return Row(
            name, 0, 0, 0, 0.0, None, math.nan, math.nan, math.nan, note=f"skipped: no DiLiGenT ball folder ({ball})"
        )
    if not (reuse and (out / "run_complete.json").is_file()):
        cmd = [sys.executable, "-m", "torchrefl.train", name, f"output.dir={out}", "--quiet", "--overwrite"]
        cmd += [f"capture.path={ball}"] if name == "diligent_ball" else []
        cmd += list(overrides)
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode:
            return Row(
                name, 0, 0, 0, 0.0, None, math.nan, math.nan, math.nan, note=f"failed: {done.stderr.strip()[-200:]}"
            )
    run = load_run(out)
    cap = capture_of(run, ball)
    with tempfile.TemporaryDirectory() as tmp:
        got = compare(run, cap.obs, cap.surface.texel_index.numpy(), cap.surface.normals.double().numpy(), Path(tmp))
    return _row(name, run, cap.obs.num_lights, got, " ".join(f"`{o}`" for o in overrides))


def _row(name: str, run: RunResult, lights: int, got: dict, note: str = "") -> Row:
    rerender = run.metrics.get("rerender", {}).get("mean_abs_diff_8bit")
    return Row(
        name,
        int(run.mask.sum()),
        lights,
        got["count"],
        got["specular"],
        rerender,
        got["fitted"],
        got["one_line"],
        got["compensated"],
        got["near_share"],
        got["fitted_near"],
        got["one_line_near"],
        note,
    )


def tiny(work: Path) -> Row:
    """A 9 x 12 spherical cap (Torrance-Sparrow, glossy and matte halves), 3 point lights, no fit."""
    H, W = 9, 12
    u, v = np.meshgrid(np.linspace(-0.6, 0.6, W), np.linspace(-0.5, 0.5, H))
    n = np.stack([u, v, np.sqrt(1.0 - u * u - v * v)], -1)
    rng = np.random.default_rng(0)
    ps = np.where((np.arange(W) < W // 2)[None, :, None], 0.3, 0.0) * np.ones((H, W, 3))
    params = dict(
        pd=rng.uniform(0.2, 0.7, (H, W, 3)),
        ps=ps,
        sigma=np.full((H, W), 0.15),
        mask=np.ones((H, W), dtype=bool),
        brdf=np.array("torrance_sparrow"),
        positions=50.0 * n,
        normals=n,
        kappa=np.full(3, math.pi),
        units=np.array("mm"),
        grid_faces=grid_triangulation(50.0 * n, np.ones((H, W), bool))[1].astype(np.int32),
    )
    folder = work / "tiny"
    folder.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(folder / "params.npz", **params)
    metrics = {"model": "local", "brdf": "torrance_sparrow", "texels": H * W, "lights": 3, "rerender": {}}
    (folder / "metrics.json").write_text(json.dumps({**metrics, "timing_s": {"total": 0.0}}))
    (folder / "config.yaml").write_text("capture:\n  kind: cylindrical_scan\n")
    write_marker(folder)
    run = load_run(folder)
    x = torch.from_numpy(params["positions"].reshape(-1, 3))
    lights = torch.tensor([[0.0, 0.0, 400.0], [150.0, 80.0, 300.0], [-200.0, -60.0, 250.0]], dtype=torch.float64)
    to = lights[:, None, :] - x[None]
    d2 = (to * to).sum(-1)
    l = to / d2.sqrt()[..., None]
    view = torch.nn.functional.normalize(torch.tensor([0.0, 0.0, 400.0]) - x, dim=-1)
    N = torch.from_numpy(n.reshape(-1, 3))
    lit = ((l * N).sum(-1) > 0) & ((view * N).sum(-1) > 0)[None]
    obs = Observations(
        intensity=torch.zeros(3, H * W, 3, dtype=torch.float64),
        valid=lit,
        saturated=torch.zeros(3, H * W, dtype=torch.bool),
        shadowed=torch.zeros(3, H * W, dtype=torch.bool),
        light_dir=l,
        falloff=1.0 / d2,
        light_intensity=torch.full((3, 3), 2.0e4, dtype=torch.float64),
        view_dir=view,
        kappa=torch.full((3,), math.pi, dtype=torch.float64),
    )
    got = compare(run, obs, np.arange(H * W), n.reshape(-1, 3), work / "tiny_export")
    return _row("tiny", run, 3, got)


def table(rows: list[Row], command: str) -> str:
    fmt = lambda x: "" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.2f}"
    lines = [
        f"Written by `{command}` on {time.strftime('%Y-%m-%d')}.",
        "",
        "| config | texels | lights | observations | median s | fit vs photos | glTF fitted | glTF one-line "
        "| fitted, base Pd / (1 - s) | near highlights: share, fitted / one-line | note |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.name} | {r.texels} | {r.lights} | {r.count} | {r.specular:.3f} | {fmt(r.fit_vs_photos)} "
            f"| {fmt(r.fitted)} | {fmt(r.one_line)} | {fmt(r.compensated)} | {_near(r)} | {r.note} |"
        )
    return "\n".join(lines) + "\n"


def _near(r: Row) -> str:
    """The near-highlight cell: the share of the observations (%), then both conversions' mean |diff| there."""
    if math.isnan(r.near_share) or math.isnan(r.fitted_near):
        return ""
    return f"{100 * r.near_share:.1f} %, {r.fitted_near:.2f} / {r.one_line_near:.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), help="bundled config names")
    ap.add_argument("--work", default="outputs/gltf_error", help="folder of the runs (WORK/NAME)")
    ap.add_argument("--reuse", action="store_true", help="reuse complete runs in WORK/NAME")
    ap.add_argument("--ball", default=None, help="the DiLiGenT ball folder (pmsData/ballPNG)")
    ap.add_argument("--tiny", action="store_true", help="a tiny scene, no fit (seconds)")
    ap.add_argument("--out", default=None, help="write the table (markdown) to this file")
    ap.add_argument(
        "--set", nargs="+", action="extend", default=[], metavar="KEY=VALUE", help="config overrides for every fit"
    )
    args = ap.parse_args(argv)
    bad = [o for o in args.set if "=" not in o]
    if bad:
        ap.error(f"--set {bad[0]}: expected KEY=VALUE")
    unknown = [c for c in args.configs if not (ROOT / "configs" / f"{c}.yaml").is_file()]
    if unknown:
        ap.error(f"configs/{unknown[0]}.yaml: no such bundled config")
    work = Path(args.work)
    ball = Path(args.ball) if args.ball else None
    if args.tiny:
        rows, command = [tiny(work)], "python scripts/gltf_error.py --tiny"
    else:
        rows = [run_config(name, work, args.reuse, ball, tuple(args.set)) for name in args.configs]
        shown = (["--ball", BALL_SHOWN] if ball else []) + (["--set", *args.set] if args.set else [])
        command = " ".join(["python scripts/gltf_error.py", "--configs", *args.configs, *shown])
    page = table(rows, command)
    print(page)
    if args.out:
        Path(args.out).write_text(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
