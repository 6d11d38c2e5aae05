"""Wavefront OBJ + MTL of a TexturedMesh with the Pd texture as map_Kd (docs/exports.md).

object.obj: `v` in the mesh's units (millimetres), `vt` per distinct corner UV, `vn` per vertex where the mesh
has normals, faces `f v/vt[/vn]`, `mtllib object.mtl`, `usemtl torchrefl`. object.mtl: Kd 1 1 1 (the texture is
the colour), Ks 0, map_Kd basecolor.png (Pd, 8-bit sRGB: what OBJ readers expect of a colour texture).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.report.export_mesh import TexturedMesh
from torchrefl.version import __version__

MATERIAL = "torchrefl"


def write_obj_mtl(obj_path: Path, mesh: TexturedMesh, texture: str) -> Path:
    """Write obj_path and the MTL beside it (same stem) whose map_Kd is `texture` (a file name beside them);
    returns the MTL's path."""
    obj_path = Path(obj_path)
    mtl_path = obj_path.with_suffix(".mtl")
    mtl_path.write_text(
        f"# torchrefl {__version__}: the fitted diffuse reflectance Pd as the colour texture\n"
        f"newmtl {MATERIAL}\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd {texture}\n"
    )
    uv, corner = np.unique(np.asarray(mesh.uvs, dtype=np.float64).reshape(-1, 2), axis=0, return_inverse=True)
    faces = np.asarray(mesh.faces, dtype=np.int64) + 1
    tex = corner.reshape(-1, 3) + 1
    lines = [
        f"# torchrefl {__version__}: the object's mesh, {mesh.units}; UVs into the texel grid (docs/exports.md)",
        f"mtllib {mtl_path.name}",
    ]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mesh.vertices]
    lines += [f"vt {u:.9g} {v:.9g}" for u, v in uv]
    if mesh.normals is not None:
        lines += [f"vn {x:.6g} {y:.6g} {z:.6g}" for x, y, z in mesh.normals]
        corners = lambda f, t: " ".join(f"{a}/{b}/{a}" for a, b in zip(f, t))
    else:
        corners = lambda f, t: " ".join(f"{a}/{b}" for a, b in zip(f, t))
    lines += [f"usemtl {MATERIAL}"]
    lines += [f"f {corners(f, t)}" for f, t in zip(faces, tex)]
    obj_path.write_text("\n".join(lines) + "\n")
    return mtl_path
