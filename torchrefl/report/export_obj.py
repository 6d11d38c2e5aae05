"""Wavefront OBJ + MTL of a TexturedMesh with the Pd texture as map_Kd (docs/exports.md).

object.obj: `v` in the mesh's units (millimetres), `vt` per distinct corner UV, `vn` per vertex where the mesh
has normals, faces `f v/vt[/vn]`, `mtllib object.mtl`, `usemtl torchrefl`. object.mtl: Kd 1 1 1 (the texture is
the colour), Ks 0, map_Kd the Pd texture (textures/basecolor.png, 8-bit sRGB: what OBJ readers expect of a
colour texture).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.report.export_mesh import TexturedMesh, unique_rows
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
    corner_uvs = np.asarray(mesh.uvs, dtype=np.float64).reshape(-1, 2)
    first, corner = unique_rows(None, corner_uvs)
    uv = corner_uvs[first]
    faces = np.asarray(mesh.faces, dtype=np.int64) + 1
    tex = corner.reshape(-1, 3) + 1
    lines = [
        f"# torchrefl {__version__}: the object's mesh, {mesh.units}; UVs into the texel grid (docs/exports.md)",
        f"mtllib {mtl_path.name}",
    ]
    # one % over a whole block of Python numbers (tolist): several times faster than numpy scalars line by line
    block = lambda fmt, a: (fmt * len(a)) % tuple(np.asarray(a).ravel().tolist())
    text = ["\n".join(lines) + "\n", block("v %.9g %.9g %.9g\n", mesh.vertices), block("vt %.9g %.9g\n", uv)]
    if mesh.normals is not None:
        text.append(block("vn %.6g %.6g %.6g\n", mesh.normals))
        face, ids = "f %d/%d/%d %d/%d/%d %d/%d/%d\n", np.stack([faces, tex, faces], -1)
    else:
        face, ids = "f %d/%d %d/%d %d/%d\n", np.stack([faces, tex], -1)
    text += [f"usemtl {MATERIAL}\n", block(face, ids.reshape(len(faces), -1))]
    obj_path.write_text("".join(text))
    return mtl_path
