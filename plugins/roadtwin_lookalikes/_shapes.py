"""Footprints and the flush mesh every look-alike shares.

Why flush: a look-alike changes how the road *looks*, not its shape: oil, tar, rubber, water,
paint and dust lie on the surface (a tar band or a paint film is ~1 mm proud). So the mesh is
the footprint at z = 0 on its boundary loop (what the merger stitches into the road) rising
over a short bevel to ``height_m`` (0: flush). Footprints are single simple polygons without
holes (the DefectModel contract): blobs (a radially perturbed ellipse), bands (a polyline
buffered by half its width: tyre marks, sealed cracks, patch seams) and rectangles (paint).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import shapely
import triangle
from shapely.geometry import LineString, Polygon

from roadtwin_core import DefectModel, RoadtwinError


def blob(rng: np.random.Generator, length_m: float, width_m: float, roughness: float,
         points: int = 96) -> np.ndarray:
    """CCW outline of an irregular blob: an ellipse whose radius is modulated by a few random
    low harmonics (``roughness``: their relative amplitude; 0 = a smooth ellipse)."""
    t = np.linspace(0.0, 2 * np.pi, points, endpoint=False)
    r = np.ones_like(t)
    for k in range(2, 7):
        r += roughness / k ** 1.5 * rng.normal() * np.cos(k * t + rng.uniform(0, 2 * np.pi))   # smooth lobes, no spikes
    r = np.clip(r, 0.45, 1.6)
    return np.column_stack([0.5 * length_m * r * np.cos(t), 0.5 * width_m * r * np.sin(t)])


def walk(rng: np.random.Generator, length_m: float, step_m: float, tortuosity: float) -> np.ndarray:
    """A polyline ~``length_m`` long along +x, heading mean-reverting (it meanders, never curls)."""
    n = max(2, int(round(length_m / step_m)))
    heading, pts = 0.0, [np.zeros(2)]
    for _ in range(n):
        heading = 0.6 * heading + rng.normal(0.0, tortuosity)
        heading = float(np.clip(heading, -0.8, 0.8))
        pts.append(pts[-1] + step_m * np.array([np.cos(heading), np.sin(heading)]))
    p = np.asarray(pts)
    return p - 0.5 * (p.min(axis=0) + p.max(axis=0))


def rectangle(length_m: float, width_m: float) -> np.ndarray:
    """CCW corners of a ``length_m`` x ``width_m`` rectangle centred on the origin, from (+x, -y)."""
    a, b = length_m / 2, width_m / 2
    return np.array([[a, -b], [a, b], [-a, b], [-a, -b]])


def band(line: np.ndarray, width_m: float) -> np.ndarray:
    """Outline of a polyline buffered by half ``width_m`` with flat ends (a band, not a sausage)."""
    poly = LineString(line).buffer(width_m / 2, quad_segs=2, cap_style="flat", join_style="mitre", mitre_limit=2.0)
    if not isinstance(poly, Polygon) or len(poly.interiors):
        raise RoadtwinError("look-alike band did not buffer to one simple polygon (internal error)")
    return np.asarray(poly.exterior.coords)[:-1]


@dataclass
class Footprint:
    """A look-alike's outline and how to mesh it: ``spacing_m`` (clipped to 1-5 cm: fine enough for
    a 3 cm band, coarse enough for a 3 m wet patch), film ``height_m`` reached over ``bevel_m``."""

    outline: np.ndarray
    spacing_m: float
    height_m: float
    bevel_m: float

    def model(self, name: str, kind: str, params) -> DefectModel:
        spacing = float(np.clip(self.spacing_m, 0.01, 0.05))
        return flush_model(name, kind, params, self.outline, spacing, self.height_m, bevel_m=self.bevel_m)


def band_footprint(line: np.ndarray, width_m: float, height_m: float) -> Footprint:
    """A band (tyre mark, sealed crack, patch seam): meshed at two thirds of its width, bevelled
    over a quarter of its width (at most 1 cm) so a narrow band still reaches its height."""
    return Footprint(band(line, width_m), width_m / 1.5, height_m, bevel_m=min(0.01, width_m / 4))


def flush_model(name: str, kind: str, params, outline: np.ndarray, spacing_m: float,
                height_m: float = 0.0, bevel_m: float = 0.01) -> DefectModel:
    """The footprint as a mesh: loop vertices first (z = 0), interior at ``height_m`` beyond a
    ``bevel_m`` ramp. Triangle keeps the loop exactly (flag Y) and refines inside."""
    poly = Polygon(outline)
    if not poly.is_valid:
        poly = shapely.make_valid(poly)
        if not isinstance(poly, Polygon):
            poly = max(getattr(poly, "geoms", [poly]), key=lambda g: g.area)
    poly = shapely.geometry.polygon.orient(poly.simplify(spacing_m / 4), 1.0)
    loop = _densify(np.asarray(poly.exterior.coords)[:-1], spacing_m)
    loop -= np.asarray(poly.centroid.coords[0])
    n = len(loop)
    ring = np.column_stack([np.arange(n), (np.arange(n) + 1) % n])
    area = max(abs(poly.area) / 60.0, spacing_m ** 2)
    out = triangle.triangulate({"vertices": loop, "segments": ring}, f"pq20Ya{area:.6f}")
    xy = out["vertices"]
    z = np.zeros(len(xy))
    if height_m > 0:
        d = shapely.distance(Polygon(loop).exterior, shapely.points(xy))
        z = height_m * np.clip(d / bevel_m, 0.0, 1.0)
        z[:n] = 0.0
    return DefectModel(name=name, defect_type=kind, vertices=np.column_stack([xy, z]), faces=out["triangles"],
                       boundary=np.arange(n), source="parametric", params=dataclasses.asdict(params))


def _densify(loop: np.ndarray, spacing: float) -> np.ndarray:
    out = []
    for a, b in zip(loop, np.roll(loop, -1, axis=0)):
        k = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing)))
        out.append(a + (b - a) * (np.arange(k)[:, None] / k))
    return np.vstack(out)
