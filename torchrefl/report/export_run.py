"""Exports of a fitted object for other tools: OBJ + MTL, glTF 2.0 (.glb), 16-bit PNG and OpenEXR maps.

    from torchrefl.report.run_result import load_run
    load_run("outputs/default").export("outputs/default_export")     # or output.export (on by default)

Formats (docs/exports.md): "maps" (maps/: report/export_maps.py), "obj" (object.obj, object.mtl, textures/) and
"glb" (object.glb) for runs with geometry (a cylindrical scan's range mesh, a mesh_views mesh); a photometric
stereo run has maps only. Errors: the output path a file (OutputError), a mesh format asked of a run without
geometry (GeometryError), a run folder that is not a complete run (RunFolderError, from load_run).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchrefl.errors import GeometryError
from torchrefl.report.export_glb import write_glb
from torchrefl.report.export_maps import specular_scale, write_textures, write_value_maps
from torchrefl.report.export_material import gltf_material
from torchrefl.report.export_mesh import TexturedMesh, read_run_mesh
from torchrefl.report.export_obj import write_obj_mtl
from torchrefl.report.run_folder import output_folder

FORMATS = ("maps", "obj", "glb")
MESH_FORMATS = ("obj", "glb")
EXPORT = "export"  # the export folder inside a run folder (output.export)
SCAN_KINDS = ("cylindrical_scan", "synthetic_cylindrical")  # capture kinds whose params.npz holds grid_faces


@dataclass(frozen=True)
class ExportInput:
    """What an export needs, on the texel grid (H, W): the estimate, the texel normals, the coverage codes (or
    None), the BRDF name and the mesh the maps lie on (None: no geometry); source names the run for messages, and
    no_mesh says why there is no mesh."""

    pd: np.ndarray
    ps: np.ndarray
    sigma: np.ndarray
    mask: np.ndarray
    normals: np.ndarray
    coverage: np.ndarray | None
    brdf: str
    mesh: TexturedMesh | None
    source: str
    no_mesh: str = "this run has no geometry (a photometric stereo run: maps only)"


@dataclass(frozen=True)
class ExportResult:
    """folder: where the files are; files: every file written (paths); formats: the formats written;
    specular_factor: the glb's KHR_materials_specular specularFactor (None without a mesh export)."""

    folder: Path
    files: tuple[Path, ...]
    formats: tuple[str, ...]
    specular_factor: float | None = None


def _formats(asked, has_mesh: bool, source: str, no_mesh: str) -> tuple[str, ...]:
    if asked is None:
        return FORMATS if has_mesh else ("maps",)
    asked = (asked,) if isinstance(asked, str) else tuple(asked)
    unknown = [f for f in asked if f not in FORMATS]
    if unknown or not asked:
        raise ValueError(f"export formats {list(asked)}: expected some of {', '.join(FORMATS)}")
    mesh_asked = [f for f in asked if f in MESH_FORMATS]
    if mesh_asked and not has_mesh:
        raise GeometryError(
            f"{source}: export format(s) {', '.join(mesh_asked)} need the object's mesh, and {no_mesh}; "
            "ask for formats=['maps']"
        )
    return asked


def export_estimate(data: ExportInput, out_dir, formats=None, option: str = "export folder") -> ExportResult:
    """Write the exports of `data` into out_dir (created; the files there of an earlier export are replaced);
    formats: some of FORMATS, None for every format the geometry allows."""
    chosen = _formats(formats, data.mesh is not None, data.source, data.no_mesh)
    folder = output_folder(str(out_dir), option)
    folder.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    if "maps" in chosen:
        files += write_value_maps(folder / "maps", data.pd, data.ps, data.sigma, data.normals, data.mask, data.coverage)
    factor = None
    if any(f in chosen for f in MESH_FORMATS):
        material = gltf_material(data.pd, data.ps, data.sigma, data.brdf)
        textures = write_textures(folder / "textures", material, data.mask)
        files += list(textures.values())
        factor = specular_scale(material, data.mask)
        if "obj" in chosen:
            obj = folder / "object.obj"
            files += [obj, write_obj_mtl(obj, data.mesh, f"textures/{textures['basecolor'].name}")]
        if "glb" in chosen:
            write_glb(folder / "object.glb", data.mesh, textures, factor)
            files.append(folder / "object.glb")
    return ExportResult(folder, tuple(files), chosen, factor)


def export_run(run, out_dir, formats=None) -> ExportResult:
    """The exports of a finished run (a RunResult, or its folder: load_run checks it) into out_dir."""
    from torchrefl.report.run_result import PARAMS, load_run

    run = load_run(run) if isinstance(run, (str, Path)) else run
    with np.load(run.folder / PARAMS, allow_pickle=False) as npz:
        params = {k: npz[k] for k in ("grid_faces", "mesh", "positions", "normals", "units") if k in npz.files}
    mesh = read_run_mesh(run.folder, params)
    section = run.config.get("capture")
    why = ExportInput.no_mesh
    if mesh is None and isinstance(section, dict) and section.get("kind") in SCAN_KINDS:
        why = "its params.npz has no 'grid_faces' (a scan run written before torchrefl exported meshes: rerun it)"
    data = ExportInput(
        run.pd, run.ps, run.sigma, run.mask, run.normals, run.coverage, run.brdf, mesh, str(run.folder), why
    )
    return export_estimate(data, out_dir, formats)
