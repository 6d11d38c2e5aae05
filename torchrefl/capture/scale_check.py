"""One check of a capture's scale: the object's size against the capture's own lengths.

A unit slip (a range image in metres read as mm, light positions in metres beside a mesh in mm) loads
and fits without any other inconsistency, to a plausible wrong answer. Its signature is a ratio of
lengths no capture has: a light or camera thousands of object radii away, or inside the object, or an
object smaller than one sampling step. Every capture kind with lengths calls `check_scale` with its
object's radius and its reference lengths (`scene_scale_check` does it for a mesh and positioned cameras
and lights), then `ScaleCheck.enforce()`: it raises for a ratio no rig has and returns warnings for one
that is possible but unusual (a factor 10, centimetres read as mm, is also a small object: only a warning).

The bands (reference length / object radius, the radius about the object's centre):
- a point light's distance from the centre: the 1/d^2 fall-off and the light directions assume the light
  outside the object. Under 1 radius it is inside the object's bounding sphere (possible only in a hollow:
  warning), under 0.5 inside any object not hollow there (error). Beyond 30 radii the fall-off varies by
  under 14 % across the object and the directions by under 4 degrees: nearly directional lights, which a
  rig of point lights would need (30/5)^2 = 36 times brighter than at 5 radii (warning); beyond 1000 radii the fall-off
  varies by under 0.4 %, one 8-bit step: the positions carry nothing the images could show (error).
- a camera's distance: inside as for lights; beyond 100 radii the object subtends under 1.2 degrees (a
  telephoto lens; warning), beyond 1000 under 0.12 degrees (a telescope; error).
- a sampling step (grid step, pixel footprint): the object's radius must span samples. Under 3 steps the
  normals' fitting window (5 samples) does not fit across it (warning), under 1 step the capture cannot
  have measured its shape (error); over 1e4 steps it needs an image over 2e4 samples across, larger than
  any scanner's or camera's (warning), over 1e5 (error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from torchrefl.errors import CaptureError, GeometryError, TorchReflError

#: reference kind -> (warning band, error band) of reference length / object radius
BANDS = {
    "light": ((1.0, 30.0), (0.5, 1000.0)),
    "camera": ((1.0, 100.0), (0.5, 1000.0)),
    "step": ((1.0e-4, 1.0 / 3.0), (1.0e-5, 1.0)),
}
#: units a slip commonly comes from: mm per unit
UNITS = {"metres": 1000.0, "inches": 25.4, "centimetres": 10.0, "micrometres": 1.0e-3}


@dataclass(frozen=True)
class ObjectSize:
    """The object's size as its geometry gives it: its radius about its centre, mm (the lengths of every capture kind
    that has lengths)."""

    radius: float
    source: str  # the file the geometry comes from, e.g. ".../range.npy"
    what: str  # its lengths in words, e.g. "the ranges"
    fix: str  # how to rescale them, with {factor} (the multiplier to mm), e.g. "give range.scale_mm: {factor:g}"
    centre: str = "the object's centre"  # what the distances are measured from


@dataclass(frozen=True, eq=False)
class Reference:
    """Lengths of one key of the capture compared with the object's radius: distances of lights or cameras from
    the object's centre ('light', 'camera'), or sampling steps ('step')."""

    kind: str
    source: str  # the file the key is in
    keys: tuple[str, ...]  # one key per value, e.g. ("lights[0].position_mm", ...)
    values: tuple[float, ...]
    fix: str = "write {keys} in {unit}"
    #: world positions (N, 3) and the object's centre (3,) the values are distances between, when they are: a unit
    #: slip scales the positions (and the geometry its centre), not the distances (None: lengths about the origin)
    positions: np.ndarray | None = None
    centre: np.ndarray | None = None

    @classmethod
    def of(cls, kind: str, source: str, key: str, values, fix: str | None = None) -> Reference:
        """A reference of one or more values; `key` with '{i}' names each value by its index."""
        vals = tuple(float(v) for v in np.atleast_1d(np.asarray(values, dtype=np.float64)))
        keys = tuple(key.format(i=i) for i in range(len(vals)))
        return cls(kind, source, keys, vals, fix or cls.fix)

    @classmethod
    def between(cls, kind: str, source: str, key: str, positions, centre) -> Reference:
        """Distances of world positions (N, 3) from the object's centre (3,)."""
        p, c = np.asarray(positions, dtype=np.float64).reshape(-1, 3), np.asarray(centre, dtype=np.float64)
        ref = cls.of(kind, source, key, np.linalg.norm(p - c, axis=-1))
        return cls(ref.kind, ref.source, ref.keys, ref.values, ref.fix, p, c)

    def rescaled(self, own: float, geometry: float) -> np.ndarray:
        """The values with this reference's lengths times `own` and the geometry's times `geometry`."""
        if self.positions is None:
            return np.asarray(self.values) * own
        return np.linalg.norm(self.positions * own - self.centre * geometry, axis=-1)

    @property
    def name(self) -> str:
        return self.keys[0] if len(self.keys) == 1 else self.keys[0].replace("[0]", "[*]")


@dataclass(frozen=True)
class Finding:
    """One value outside its kind's warning band."""

    severity: str  # "error" or "warning"
    reference: Reference
    key: str
    value: float
    ratio: float  # value / object radius

    def describe(self, centre: str) -> str:
        if self.reference.kind == "step":
            return f"{self.key} = {self.value:.4g} mm: the object's radius spans {_num(1.0 / self.ratio)} such steps"
        return f"{self.key} is {self.value:.4g} mm from {centre}: {_num(self.ratio)} object radii"

    @property
    def deviation(self) -> float:
        """|log| of the ratio over its band's centre: how far out it is."""
        return abs(math.log(max(self.ratio, 1e-300) / _typical(self.reference.kind)))


@dataclass
class ScaleCheck:
    """The verdict: the values outside their bands, and which side looks wrong by what factor."""

    obj: ObjectSize
    references: list[Reference]
    findings: list[Finding] = field(default_factory=list)
    #: (reference, factor): None = the geometry; factor: the unit's mm (UNITS) that would bring its lengths in place
    #: (a reference out of band in every unit, a single light out of place, is only listed)
    suspects: list[tuple[Reference | None, float]] = field(default_factory=list)

    @property
    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "error"]

    @property
    def warnings(self) -> list[Finding]:
        return [f for f in self.findings if f.severity == "warning"]

    def _verdict(self) -> str:
        parts = []
        for ref, factor in self.suspects:
            if ref is None:
                fix = self.obj.fix.format(factor=factor)
                parts.append(f"{self.obj.what} {_looks(factor)} next to the capture's other lengths; {fix}")
            else:
                fix = ref.fix.format(keys=ref.name, unit="mm")
                parts.append(
                    f"{ref.name} in {ref.source} {_looks(factor)} next to the object and the other lengths; {fix}"
                )
        return "; ".join(parts)

    def message(self, findings: list[Finding]) -> str:
        """The findings (the farthest out of each reference, with how many of its values are out) and the verdict."""
        items = []
        for ref in self.references:
            mine = [f for f in findings if f.reference is ref]
            if mine:
                worst = max(mine, key=lambda f: f.deviation)
                more = f" ({len(mine)} of the {len(ref.keys)} {ref.name} alike)" if len(ref.keys) > 1 else ""
                items.append(f"{ref.source}: {worst.describe(self.obj.centre)}{more}")
        verdict = self._verdict()
        return (
            f"{self.obj.source}: "
            + (f"{verdict}. The" if verdict else "the")
            + f" object's radius is {self.obj.radius:.4g} mm, but "
            + "; ".join(items)
            + " (the bands: docs/capture-formats.md, 'The capture's scale')"
        )

    def enforce(self, error: type[TorchReflError] | None = None) -> list[str]:
        """Raise for a ratio outside an error band (`error`; None: GeometryError when the geometry looks wrong, else
        CaptureError); else the warnings' message (one, none when every ratio is in its band)."""
        if self.errors:
            if error is None:
                error = GeometryError if any(ref is None for ref, _ in self.suspects) else CaptureError
            raise error(self.message(self.errors))
        return [self.message(self.warnings)] if self.warnings else []


def unit_name(factor: float) -> str:
    """The name of the unit (UNITS) whose size in mm is nearest `factor`."""
    return min(UNITS, key=lambda u: abs(math.log(factor / UNITS[u])))


def _looks(factor: float) -> str:
    return f"look like {unit_name(factor)} (x {factor:g} gives mm)"


def _num(x: float) -> str:
    return f"{x:.3g}" if x == 0 or 1e-3 <= x < 1e4 else f"{x:.1e}"


def _typical(kind: str) -> float:
    lo, hi = BANDS[kind][0]
    return math.sqrt(lo * hi)


def _in_band(ref: Reference, radius: float, geometry: float = 1.0, own: float = 1.0) -> bool:
    """Every value of `ref` within its kind's warning band with the geometry's lengths (the object's `radius`
    included) times `geometry` and the reference's times `own`."""
    lo, hi = BANDS[ref.kind][0]
    ratios = ref.rescaled(own, geometry) / (radius * geometry)
    return bool(((ratios >= lo) & (ratios <= hi)).all())


def _likeliest(scales: list[float], typical_log: float) -> float:
    """Of several unit factors that fit equally well, the one nearest the typical factor (exp(typical_log))."""
    return min(scales, key=lambda k: abs(math.log(k) - typical_log))


def check_scale(obj: ObjectSize, references: list[Reference]) -> ScaleCheck:
    """Compare each reference length with the object's radius (the bands: the module's docstring).

    Which side looks wrong, when a value is out of its band: the unit factor (1 or one of UNITS) of the geometry that
    puts the most references wholly in their bands is the geometry's (1 on a tie with 1: the geometry is trusted
    first); a reference still out of band with that factor is suspect itself when a unit puts it in band (a single
    light out of place is only listed)."""
    if not (math.isfinite(obj.radius) and obj.radius > 0):
        raise GeometryError(f"{obj.source}: the object's radius is {obj.radius!r}, expected a positive length")
    references = [r for r in references if r.values]
    result = ScaleCheck(obj, references)
    logs = []
    for ref in references:
        (wlo, whi), (elo, ehi) = BANDS[ref.kind]
        ratios = np.asarray(ref.values) / obj.radius
        for key, value, ratio in zip(ref.keys, ref.values, ratios):
            if not (math.isfinite(ratio) and ratio > 0) or not elo <= ratio <= ehi:
                result.findings.append(Finding("error", ref, key, value, float(ratio)))
            elif not wlo <= ratio <= whi:
                result.findings.append(Finding("warning", ref, key, value, float(ratio)))
        positive = ratios[np.isfinite(ratios) & (ratios > 0)]
        if positive.size:
            logs.append(float(np.median(np.log(positive / _typical(ref.kind)))))
    if not result.findings:
        return result
    typical_log = float(np.median(logs)) if logs else 0.0
    agree = {k: sum(_in_band(ref, obj.radius, k) for ref in references) for k in (1.0, *UNITS.values())}
    best = max(agree.values())
    scale = 1.0 if agree[1.0] == best else _likeliest([k for k, n in agree.items() if n == best], typical_log)
    if scale != 1.0:
        result.suspects.append((None, scale))
    for ref in references:
        if not _in_band(ref, obj.radius, scale):
            fits = [m for m in UNITS.values() if _in_band(ref, obj.radius, scale, m)]
            values = np.asarray(ref.values)
            values = values[np.isfinite(values) & (values > 0)]
            ref_log = (
                float(np.median(np.log(values / (_typical(ref.kind) * obj.radius * scale)))) if values.size else 0.0
            )
            if fits:
                result.suspects.append((ref, _likeliest(fits, -ref_log)))
    return result


def bounding_sphere(points) -> tuple[np.ndarray, float]:
    """(centre, radius) of the finite points (N, 3): the bounding box's centre and the farthest point from it."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(-1)]
    if not len(p):
        return np.zeros(3), 0.0
    centre = (p.min(0) + p.max(0)) / 2.0
    return centre, float(np.linalg.norm(p - centre, axis=-1).max())


@dataclass(frozen=True)
class Positions:
    """World positions (N, 3), mm, of the cameras or the lights of a capture, and where they are written."""

    source: str  # the file
    key: str  # the key of position i, with '{i}', e.g. "cameras[{i}].position_mm"
    positions: np.ndarray


def scene_scale_check(
    vertices, geometry: str, fix: str, *, cameras: Positions | None = None, lights: Positions | None = None
) -> ScaleCheck:
    """check_scale of a mesh (its vertices (N, 3), mm, from the file `geometry`; `fix` as ObjectSize's) against
    positioned cameras and point lights: their distances from the centre of the mesh's bounding sphere, in 3-D."""
    centre, radius = bounding_sphere(vertices)
    refs = []
    for kind, spec in (("camera", cameras), ("light", lights)):
        if spec is not None:
            refs.append(Reference.between(kind, spec.source, spec.key, spec.positions, centre))
    return check_scale(ObjectSize(radius, geometry, "the mesh's vertices", fix), refs)
