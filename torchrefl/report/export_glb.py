"""A glTF 2.0 binary (.glb) of a TexturedMesh with the converted material (report/export_material.py).

Written from the glTF 2.0 specification's container layout (12-byte header, a JSON chunk padded with spaces and a
BIN chunk padded with zeros, each 4-byte aligned): one mesh, one node, one material. Positions in metres (glTF's
unit; the run's millimetres / 1000), texture coordinates with v flipped (glTF's origin is the image's top-left),
vertices split where a position has several UVs. The material: pbrMetallicRoughness with baseColorTexture (Pd,
sRGB), metallicFactor 0, roughnessFactor 1 and metallicRoughnessTexture (G roughness); KHR_materials_specular with
specularFactor (the largest strength), specularTexture (A: strength / specularFactor), specularColorFactor 25 and
specularColorTexture (the specular colour t, sRGB), so that f0 = strength * t. Double-sided: a scan is a sheet.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from torchrefl.report.export_material import SPECULAR_COLOR_FACTOR
from torchrefl.report.export_mesh import TexturedMesh, unique_rows
from torchrefl.version import __version__

GLB_MAGIC = 0x46546C67  # "glTF"
JSON_CHUNK = 0x4E4F534A  # "JSON"
BIN_CHUNK = 0x004E4942  # "BIN\0"
FLOAT, UINT32 = 5126, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
LINEAR, LINEAR_MIPMAP_LINEAR, REPEAT = 9729, 9987, 10497
METRES_PER_UNIT = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254}
SPECULAR_EXTENSION = "KHR_materials_specular"


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


class _Buffer:
    """The BIN chunk as it is built, with its bufferViews and accessors."""

    def __init__(self):
        self.data = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, blob: bytes, target: int | None = None) -> int:
        self.data += b"\0" * (-len(self.data) % 4)
        self.views.append(
            {
                "buffer": 0,
                "byteOffset": len(self.data),
                "byteLength": len(blob),
                **({"target": target} if target else {}),
            }
        )
        self.data += blob
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, bounds: bool = False) -> int:
        ctype = UINT32 if array.dtype == np.uint32 else FLOAT
        entry = {"bufferView": self.view(array.tobytes(), target), "componentType": ctype, "count": len(array)}
        entry["type"] = kind
        if bounds:
            entry.update(min=array.min(axis=0).tolist(), max=array.max(axis=0).tolist())
        self.accessors.append(entry)
        return len(self.accessors) - 1


def split_vertices(mesh: TexturedMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """(positions (N, 3), uvs (N, 2), triangles (F, 3), normals (N, 3) or None): one glTF vertex per distinct
    (vertex, uv) pair of the mesh's corners."""
    vids = np.asarray(mesh.faces, dtype=np.int64).reshape(-1)
    uvs = np.asarray(mesh.uvs, dtype=np.float64).reshape(-1, 2)
    first, inverse = unique_rows(vids, uvs)
    vid = vids[first]
    normals = None if mesh.normals is None else np.asarray(mesh.normals)[vid]
    return np.asarray(mesh.vertices)[vid], uvs[first], inverse.reshape(-1, 3), normals


def write_glb(path: Path, mesh: TexturedMesh, textures: dict[str, Path], specular_factor: float) -> None:
    """Write the .glb: `textures` maps basecolor, roughness, specular, specular_color to PNG files (embedded)."""
    buf = _Buffer()
    positions, uvs, triangles, normals = split_vertices(mesh)
    scale = METRES_PER_UNIT.get(mesh.units, 1.0)
    attributes = {
        "POSITION": buf.accessor((positions * scale).astype(np.float32), "VEC3", ARRAY_BUFFER, bounds=True),
        "TEXCOORD_0": buf.accessor(np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], -1).astype(np.float32), "VEC2", ARRAY_BUFFER),
    }
    if normals is not None:
        unit = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        attributes["NORMAL"] = buf.accessor(unit.astype(np.float32), "VEC3", ARRAY_BUFFER)
    indices = buf.accessor(triangles.reshape(-1).astype(np.uint32), "SCALAR", ELEMENT_ARRAY_BUFFER)
    order = ("basecolor", "roughness", "specular", "specular_color")
    images = [{"bufferView": buf.view(Path(textures[name]).read_bytes()), "mimeType": "image/png"} for name in order]
    tex = {name: {"index": i} for i, name in enumerate(order)}
    material = {
        "name": "torchrefl",
        "doubleSided": True,
        "pbrMetallicRoughness": {
            "baseColorTexture": tex["basecolor"],
            "metallicFactor": 0.0,
            "roughnessFactor": 1.0,
            "metallicRoughnessTexture": tex["roughness"],
        },
        "extensions": {
            SPECULAR_EXTENSION: {
                "specularFactor": float(specular_factor),
                "specularTexture": tex["specular"],
                "specularColorFactor": [SPECULAR_COLOR_FACTOR] * 3,
                "specularColorTexture": tex["specular_color"],
            }
        },
    }
    doc = {
        "asset": {"version": "2.0", "generator": f"torchrefl {__version__}"},
        "extensionsUsed": [SPECULAR_EXTENSION],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "object"}],
        "meshes": [{"name": "object", "primitives": [{"attributes": attributes, "indices": indices, "material": 0}]}],
        "materials": [material],
        "samplers": [{"magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR, "wrapS": REPEAT, "wrapT": REPEAT}],
        "textures": [{"sampler": 0, "source": i} for i in range(len(order))],
        "images": images,
        "accessors": buf.accessors,
        "bufferViews": buf.views,
        "buffers": [{"byteLength": len(buf.data)}],
    }
    blob = _pad(bytes(buf.data), b"\0")
    text = _pad(json.dumps(doc, separators=(",", ":")).encode(), b" ")
    total = 12 + 8 + len(text) + 8 + len(blob)
    Path(path).write_bytes(
        struct.pack("<III", GLB_MAGIC, 2, total)
        + struct.pack("<II", len(text), JSON_CHUNK)
        + text
        + struct.pack("<II", len(blob), BIN_CHUNK)
        + blob
    )
