"""The glTF 2.0 metallic-roughness BRDF with KHR_materials_specular, and a .glb material reader, written from the
specifications; it shares no code with torchrefl (numpy, pygltflib and Pillow only).

glTF 2.0, Appendix B (BRDF implementation):
    material = mix(dielectric_brdf, metal_brdf, metallic)
    metal_brdf = conductor_fresnel(f0 = baseColor, bsdf = specular_brdf(a))
    specular_brdf(a) = V * D,  a = roughness^2
    D = a^2 X+(N.H) / (pi ((N.H)^2 (a^2 - 1) + 1)^2)                        (Trowbridge-Reitz / GGX)
    V = X+(H.L) / (|N.L| + sqrt(a^2 + (1 - a^2)(N.L)^2))
      * X+(H.V) / (|N.V| + sqrt(a^2 + (1 - a^2)(N.V)^2))                     (separable Smith, G / (4 |N.L| |N.V|))
    conductor_fresnel: bsdf * (f0 + (1 - f0)(1 - |V.H|)^5)
    diffuse_brdf = (1 / pi) baseColor
KHR_materials_specular (ratified), its implementation section:
    dielectric_f0 = min(0.04 * specularColor, 1) * specular,   dielectric_f90 = specular
    dielectric_fresnel = dielectric_f0 + (dielectric_f90 - dielectric_f0)(1 - |V.H|)^5
    dielectric_brdf = dielectric_fresnel * specular_brdf + (1 - max_value(dielectric_fresnel)) * diffuse_brdf
    specular = specularFactor * specularTexture.a,  specularColor = specularColorFactor * specularColorTexture.rgb
    (the colour texture sRGB-encoded, the strength texture linear).
Textures: baseColorTexture sRGB-encoded RGB(A); metallicRoughnessTexture linear, G roughness, B metallic, times
roughnessFactor / metallicFactor; baseColorFactor multiplies the base colour.
"""

from __future__ import annotations

import io
import math

import numpy as np


def _unit(x):
    x = np.asarray(x, dtype=np.float64)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def gltf_brdf(n, l, v, base_color, roughness, metallic=0.0, specular=1.0, specular_color=1.0):
    """f(l, v) (..., 3) of the glTF material; n, l, v (..., 3) (normalised here); base_color (..., 3) linear;
    roughness, metallic, specular (...); specular_color (..., 3) or a scalar (the product factor * texture)."""
    n, l, v = _unit(n), _unit(l), _unit(v)
    h = _unit(l + v)
    nl, nv, nh, vh, hl = _dot(n, l), _dot(n, v), _dot(n, h), _dot(v, h), _dot(h, l)
    a2 = np.asarray(roughness, dtype=np.float64) ** 4
    step = lambda x: (x > 0).astype(np.float64)
    D = a2 * step(nh) / (math.pi * (nh * nh * (a2 - 1.0) + 1.0) ** 2)
    V = (step(hl) / (np.abs(nl) + np.sqrt(a2 + (1 - a2) * nl * nl))) * (
        step(vh) / (np.abs(nv) + np.sqrt(a2 + (1 - a2) * nv * nv))
    )
    spec = (V * D)[..., None]
    schlick = ((1.0 - np.abs(vh)) ** 5)[..., None]
    base = np.asarray(base_color, dtype=np.float64)
    metal = spec * (base + (1.0 - base) * schlick)
    s = np.asarray(specular, dtype=np.float64)[..., None]
    f0 = np.minimum(0.04 * np.asarray(specular_color, dtype=np.float64), 1.0) * s
    fresnel = f0 + (s - f0) * schlick
    dielectric = fresnel * spec + (1.0 - fresnel.max(axis=-1, keepdims=True)) * base / math.pi
    m = np.asarray(metallic, dtype=np.float64)[..., None]
    return (1.0 - m) * dielectric + m * metal


def srgb_to_linear(c):
    """The sRGB transfer function's inverse (IEC 61966-2-1), c in [0, 1]."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


class GlbMaterial:
    """The first material of a .glb read with pygltflib, its textures decoded with Pillow (images in the file's
    binary chunk): base_color (H, W, 3) linear, roughness, metallic, specular (H, W), specular_color (H, W, 3)
    (factors applied), and the file's mesh: positions (N, 3), uvs (N, 2) (glTF's, v down), indices (F, 3)."""

    def __init__(self, path):
        import pygltflib
        from PIL import Image

        g = pygltflib.GLTF2().load(str(path))
        blob = g.binary_blob()
        self.gltf = g

        def view(index):
            bv = g.bufferViews[index]
            return blob[bv.byteOffset or 0 : (bv.byteOffset or 0) + bv.byteLength]

        def image(texture_info):
            source = g.textures[texture_info.index].source
            return np.asarray(Image.open(io.BytesIO(view(g.images[source].bufferView)))).astype(np.float64) / 255.0

        def accessor(index, width, dtype):
            a = g.accessors[index]
            return np.frombuffer(view(a.bufferView), dtype=dtype, count=a.count * width).reshape(a.count, width)

        mat = g.materials[0]
        pbr = mat.pbrMetallicRoughness
        base = srgb_to_linear(image(pbr.baseColorTexture)[..., :3])
        self.base_color = base * np.asarray(pbr.baseColorFactor[:3])
        mr = image(pbr.metallicRoughnessTexture)
        self.roughness = mr[..., 1] * pbr.roughnessFactor
        self.metallic = mr[..., 2] * pbr.metallicFactor
        ext = (mat.extensions or {}).get("KHR_materials_specular", {})
        shape = self.roughness.shape
        strength = image(_Info(ext["specularTexture"]))[..., 3] if "specularTexture" in ext else np.ones(shape)
        self.specular = strength * ext.get("specularFactor", 1.0)
        colour = (
            srgb_to_linear(image(_Info(ext["specularColorTexture"]))[..., :3])
            if "specularColorTexture" in ext
            else np.ones(shape + (3,))
        )
        self.specular_color = colour * np.asarray(ext.get("specularColorFactor", [1.0, 1.0, 1.0]))
        prim = g.meshes[0].primitives[0]
        self.positions = accessor(prim.attributes.POSITION, 3, np.float32)
        self.uvs = accessor(prim.attributes.TEXCOORD_0, 2, np.float32)
        self.indices = accessor(prim.indices, 1, np.uint32).reshape(-1, 3)

    def at_texels(self, rows, cols) -> dict:
        """The material's parameters at texture pixels (rows, cols) (nearest: the texel grid is the texture)."""
        return dict(
            base_color=self.base_color[rows, cols],
            roughness=self.roughness[rows, cols],
            metallic=self.metallic[rows, cols],
            specular=self.specular[rows, cols],
            specular_color=self.specular_color[rows, cols],
        )


class _Info:
    """A textureInfo given as the JSON dict an extension holds."""

    def __init__(self, d):
        self.index = d["index"]
