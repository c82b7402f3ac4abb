"""The boolean merger (plugin roadtwin_boolean) against the CDT merger and independent references.

Both mergers are taken from the plugin manager by name. References are computed here, not taken
from either merger: segment areas from shapely, defect volumes from the defect models' own
closed forms (``DefectModel.volume_m3`` * sx * sy * sz for the built-in types; for our analytic
ring-stack defects an exact closed form of the piecewise-linear surface), heights from the
surface model, top-surface heights by point location (shapely STRtree) + barycentric
interpolation in each merger's own triangles.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import shapely
import shapely.affinity
import triangle
import trimesh
from shapely.geometry import Polygon, box

from roadtwin_core import (ComposeRules, DefectModel, MergedSegment, Placement, PluginManager, RoadSegment,
                           RoadtwinError, SampledSurface, describe_params, make_params)

REPO = Path(__file__).resolve().parents[2]
PM = PluginManager()
CDT = PM.get("mergers", "cdt")
BOOL = PM.get("mergers", "boolean")
TYPES = PM.registry("defect_types")
RULES = ComposeRules()


# --------------------------------------------------------------------------- builders
def make_segment(poly: Polygon, sid: str = "seg") -> RoadSegment:
    """A plain (no quality) constrained triangulation of the polygon as the layout mesh."""
    c = np.asarray(poly.exterior.coords)[:-1, :2]
    n = len(c)
    segments = np.column_stack([np.arange(n), (np.arange(n) + 1) % n])
    out = triangle.triangulate({"vertices": c, "segments": segments}, "p")
    return RoadSegment(sid, "driving", out["vertices"], out["triangles"])


def ring_stack(name: str, n: int, radii: list[float], z: list[float]) -> tuple[DefectModel, float]:
    """A piecewise-linear 'analytic bowl': a centre vertex at ``z[0]`` and concentric regular
    n-gons of ``radii`` (aligned, the last is the footprint) at ``z[1:]`` (the last is 0).
    Returns the model and its exact signed volume, in closed form: with s = sin(2 pi / n),
    centre fan n s/2 r1^2 (z0 + 2 z1)/3, and each annulus a -> b
    n s/2 (rb - ra) (rb (za + 2 zb) + ra (2 za + zb)) / 3."""
    assert len(z) == len(radii) + 1 and z[-1] == 0.0
    t = 2 * np.pi * np.arange(n) / n
    pts = [np.zeros((1, 2))] + [np.column_stack([r * np.cos(t), r * np.sin(t)]) for r in radii]
    zz = np.concatenate([[z[0]]] + [np.full(n, zi) for zi in z[1:]])
    k = np.arange(n)
    faces = [np.column_stack([np.zeros(n, int), 1 + k, 1 + (k + 1) % n])]
    for j in range(len(radii) - 1):
        a, b = 1 + j * n, 1 + (j + 1) * n
        faces.append(np.column_stack([a + k, b + k, b + (k + 1) % n]))
        faces.append(np.column_stack([a + k, b + (k + 1) % n, a + (k + 1) % n]))
    boundary = 1 + (len(radii) - 1) * n + k
    model = DefectModel(name, "analytic", np.column_stack([np.concatenate(pts), zz]), np.concatenate(faces), boundary)
    s = math.sin(2 * math.pi / n)
    vol = n * s / 2 * radii[0] ** 2 * (z[0] + 2 * z[1]) / 3
    for j in range(len(radii) - 1):
        ra, rb, za, zb = radii[j], radii[j + 1], z[j + 1], z[j + 2]
        vol += n * s / 2 * (rb - ra) * (rb * (za + 2 * zb) + ra * (2 * za + zb)) / 3
    return model, vol


def real(kind: str, seed: int, **params) -> DefectModel:
    t = TYPES[kind]
    return t.generate(t.Params(**params), np.random.default_rng(seed), f"{kind}{seed}")


def reference_signed_volume(p: Placement, analytic: dict[str, float]) -> float:
    """Independent signed volume (+ added material, - removed) of one placement."""
    sx, sy, sz = p.scale
    if p.model.name in analytic:
        return analytic[p.model.name] * sx * sy * sz
    sign = 1.0 if p.model.defect_type == "bump" or p.model.height_m > 0 else -1.0
    return sign * p.model.volume_m3 * sx * sy * sz


def scene() -> tuple[Polygon, list[Placement], dict[str, float]]:
    """An L-shaped 16 m x 9 m segment, rotated and shifted, with eight defects: real potholes, a
    real bump, a raised manhole, a real depression, and analytic bowls: a frustum pit, a pyramid
    bump, and a mixed-sign 'lipped pit' (pit at the centre, raised lip ring)."""
    poly = box(0, 0, 16, 9).difference(box(11, 5.5, 16, 9))
    frustum, v_frustum = ring_stack("frustum", 48, [0.25, 0.4], [-0.06, -0.06, 0.0])
    pyramid, v_pyramid = ring_stack("pyramid", 40, [0.5], [0.05, 0.0])
    lipped, v_lipped = ring_stack("lipped", 48, [0.2, 0.45, 0.6], [-0.05, -0.04, 0.015, 0.0])
    analytic = {"frustum": v_frustum, "pyramid": v_pyramid, "lipped": v_lipped}
    placements = [
        Placement("pot1", real("pothole", 1, radius_m=0.35, depth_m=0.08), 2.0, 2.0, 0.3),
        Placement("pot2", real("pothole", 2, radius_m=0.25, depth_m=0.05), 4.5, 6.8, 1.1, (1.1, 0.9, 1.2)),
        Placement("bump", real("bump", 3, length_m=0.8, width_m=3.0, height_m=0.07), 7.5, 4.0, 0.15),
        Placement("manhole", real("manhole", 4, diameter_m=0.7, offset_m=0.02), 10.0, 1.8, 0.0),
        Placement("depr", real("depression", 5, length_m=2.0, width_m=1.2, depth_m=0.03), 13.5, 2.5, 0.4),
        Placement("frustum", frustum, 2.0, 5.0, 0.2),
        Placement("pyramid", pyramid, 9.5, 7.5, 0.0, (1.2, 0.8, 1.0)),
        Placement("lipped", lipped, 5.0, 3.0, 0.7),
    ]
    # sanity of the scene itself: inside, apart
    fps = [Polygon(p.world_footprint()) for p in placements]
    for i, a in enumerate(fps):
        assert poly.buffer(-0.3).contains(a), placements[i].instance_id
        for b in fps[i + 1:]:
            assert a.distance(b) > 0.3
    angle, dx, dy = 23.0, 31.7, -12.4
    poly = shapely.affinity.translate(shapely.affinity.rotate(poly, angle, origin=(0, 0)), dx, dy)
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    moved = [Placement(p.instance_id, p.model, c * p.x - s * p.y + dx, s * p.x + c * p.y + dy,
                       p.yaw + math.radians(angle), p.scale) for p in placements]
    return poly, moved, analytic


def plane_surface(bounds, gx: float, gy: float, z0: float, wave: float = 0.0) -> SampledSurface:
    """Scattered samples (k-d tree + local plane fit: exact on a plane) of z0 + gx x + gy y,
    plus an optional gentle wave (then no longer planar)."""
    x0, y0, x1, y1 = bounds
    rng = np.random.default_rng(11)
    X, Y = np.meshgrid(np.arange(x0 - 1, x1 + 1, 0.35), np.arange(y0 - 1, y1 + 1, 0.35))
    X = X + rng.uniform(-0.1, 0.1, X.shape)
    Y = Y + rng.uniform(-0.1, 0.1, Y.shape)
    Z = z0 + gx * X + gy * Y + wave * np.sin(0.8 * X) * np.cos(0.6 * Y)
    return SampledSurface(np.column_stack([X.ravel(), Y.ravel(), Z.ravel()]))


# --------------------------------------------------------------------------- measurements
def xy_areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    a, b, c = v[f[:, 0], :2], v[f[:, 1], :2], v[f[:, 2], :2]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def removed_volume(m: MergedSegment, owner: int, surface) -> float:
    """Integral of (surface - z) over the faces owned by ``owner`` (exact for linear z)."""
    v, f = m.part(owner)
    if len(f) == 0:
        return 0.0
    d = surface.height(v[:, :2]) - v[:, 2]
    return float((xy_areas(v, f) * d[f].mean(axis=1)).sum())


def locate(m: MergedSegment, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height and owner of the top surface at each point (NaN / -2 where none is found)."""
    f = m.faces[xy_areas(m.vertices, m.faces) > 1e-14]
    owner_of = m.face_owner[xy_areas(m.vertices, m.faces) > 1e-14]
    tree = shapely.STRtree(shapely.polygons(m.vertices[f][:, :, :2]))
    pi, ti = tree.query(shapely.points(xy), predicate="intersects")
    z = np.full(len(xy), np.nan)
    own = np.full(len(xy), -2)
    tri = m.vertices[f[ti]]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    p = xy[pi]
    u = ((p[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (p[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) / det
    w = ((b[:, 0] - a[:, 0]) * (p[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (p[:, 0] - a[:, 0])) / det
    z[pi] = (1 - u - w) * a[:, 2] + u * b[:, 2] + w * c[:, 2]
    own[pi] = owner_of[ti]
    return z, own


def grid_away_from_rims(poly: Polygon, placements: list[Placement], step: float, margin: float) -> np.ndarray:
    x0, y0, x1, y1 = poly.bounds
    X, Y = np.meshgrid(np.arange(x0, x1, step) + step / 3, np.arange(y0, y1, step) + step / 7)
    pts = np.column_stack([X.ravel(), Y.ravel()])
    keep = shapely.contains_xy(poly.buffer(-margin), pts[:, 0], pts[:, 1])
    rims = shapely.union_all([Polygon(p.world_footprint()).boundary for p in placements])
    keep &= shapely.distance(rims, shapely.points(pts)) > margin
    return pts[keep]


def closed_solid(build) -> trimesh.Trimesh:
    """The boolean merger's solid, checked closed by manifold3d and (independently) by trimesh."""
    import manifold3d

    assert build.solid.status() == manifold3d.Error.NoError
    mesh = build.solid.to_mesh64()
    tm = trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume > 0
    return tm


# --------------------------------------------------------------------------- tests
def test_registered_with_typed_params():
    from roadtwin_boolean import BooleanMerger

    assert isinstance(BOOL, BooleanMerger) and BOOL.name == "boolean" and BOOL.description
    names = {d["name"]: d for d in describe_params(BOOL.Params)}
    assert names["thickness_m"]["default"] == 0.3 and names["thickness_m"]["lo"] > 0
    with pytest.raises(RoadtwinError, match="thickness_m"):
        make_params(BOOL.Params, {"thickness_m": -1.0}, "merger boolean")
    with pytest.raises(RoadtwinError, match="thickness_m"):
        BooleanMerger(BOOL.Params(thickness_m=float("nan")))


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.04, -0.025)], ids=["flat", "tilted"])
def test_boolean_matches_cdt_and_references(tilt):
    poly, placements, analytic = scene()
    seg = make_segment(poly)
    surface = plane_surface(poly.bounds, *tilt, z0=3.0)
    t0 = time.perf_counter()
    mc = CDT.merge(seg, placements, surface, RULES)
    t1 = time.perf_counter()
    build = BOOL.build(seg, placements, surface, RULES)
    t2 = time.perf_counter()
    mb = build.merged
    print(f"\n[{tilt}] cdt {t1 - t0:.3f} s, boolean {t2 - t1:.3f} s; faces cdt {len(mc.faces)} boolean {len(mb.faces)}")

    # top surfaces tile the segment: XY area, every face counter-clockwise, no overlap
    for m in (mc, mb):
        a = xy_areas(m.vertices, m.faces)
        assert math.isclose(a.sum(), poly.area, rel_tol=1e-6)
        assert (a > 0).all()
        union = shapely.union_all(shapely.polygons(m.vertices[m.faces][:, :, :2]))
        assert union.symmetric_difference(poly).area <= 1e-9 * poly.area
    # a planar surface leaves no rim steps; the sheet is one manifold: every edge in <= 2 faces
    assert len(mb.ring_faces) == 0
    e = np.sort(np.concatenate([mb.faces[:, [0, 1]], mb.faces[:, [1, 2]], mb.faces[:, [2, 0]]]), axis=1)
    assert np.unique(e, axis=0, return_counts=True)[1].max() <= 2
    # road vertices on the surface; every defect face's vertices at surface + relative height
    rv, _ = mb.part(-1)
    assert np.abs(rv[:, 2] - surface.height(rv[:, :2])).max() <= 1e-9

    # the solid: watertight, genus 0, volume = slab - cut + added, each from an independent reference
    refs = [reference_signed_volume(p, analytic) for p in placements]
    expected = build.thickness_m * poly.area + sum(refs)
    tm = closed_solid(build)
    assert tm.euler_number == 2  # one closed sheet, genus 0
    assert math.isclose(build.solid.volume(), expected, rel_tol=1e-9), (build.solid.volume(), expected)
    assert math.isclose(tm.volume, expected, rel_tol=1e-9)

    # per defect: removed volume (surface - z) over its faces, CDT vs boolean vs reference
    for i, p in enumerate(placements):
        vc, vb = removed_volume(mc, i, surface), removed_volume(mb, i, surface)
        assert math.isclose(vb, vc, rel_tol=0.01), (p.instance_id, vc, vb)
        assert math.isclose(vb, -refs[i], rel_tol=1e-6), (p.instance_id, vb, -refs[i])
        area = xy_areas(*mb.part(i)).sum()
        assert math.isclose(area, p.model.area_m2 * p.scale[0] * p.scale[1], rel_tol=1e-9)
    assert sorted(set(mb.face_owner.tolist())) == list(range(-1, len(placements)))

    # heights and owners agree at a grid of points away from defect rims and the border
    pts = grid_away_from_rims(poly, placements, 0.07, 0.01)
    zc, oc = locate(mc, pts)
    zb, ob = locate(mb, pts)
    assert np.isfinite(zc).all() and np.isfinite(zb).all()
    assert np.abs(zc - zb).max() < 1e-6  # planar surface: exact up to rounding (spec: < 2 mm)
    assert (oc == ob).all()


@pytest.mark.parametrize("rims", [True, False], ids=["rims-in-road", "plain-road"])
def test_curved_surface(rims):
    """On a curved surface the road is linear between its vertices while a defect rim has exact
    surface heights. With the rims built into the road mesh (default) they meet without a step;
    on the plain even mesh the boolean keeps small vertical rim steps as road ring faces."""
    from roadtwin_boolean import BooleanMerger, BooleanParams

    merger = BooleanMerger(BooleanParams(rim_constraints=rims))
    poly, placements, analytic = scene()
    seg = make_segment(poly)
    surface = plane_surface(poly.bounds, 0.03, 0.01, z0=-2.0, wave=0.04)
    mc = CDT.merge(seg, placements, surface, RULES)
    build = merger.build(seg, placements, surface, RULES)
    mb = build.merged
    a = xy_areas(mb.vertices, mb.faces)
    assert math.isclose(a.sum(), poly.area, rel_tol=1e-6)
    ring = mb.faces[mb.ring_faces]
    if rims:
        assert len(mb.ring_faces) == 0 and (a > 0).all()
    else:
        assert len(mb.ring_faces) > 0
        assert (mb.face_owner[mb.ring_faces] == -1).all()
        assert np.abs(xy_areas(mb.vertices, ring)).max() < 1e-9  # vertical
        assert np.ptp(mb.vertices[ring][:, :, 2], axis=1).max() < 5e-3  # small
        non_ring = np.setdiff1d(np.arange(len(mb.faces)), mb.ring_faces)
        assert (a[non_ring] > -1e-12).all()
    # the top sheet is one manifold surface whose only border is the segment outline
    e = np.sort(np.concatenate([mb.faces[:, [0, 1]], mb.faces[:, [1, 2]], mb.faces[:, [2, 0]]]), axis=1)
    key, count = np.unique(e, axis=0, return_counts=True)
    assert count.max() <= 2
    border = key[count == 1]
    mid = 0.5 * (mb.vertices[border[:, 0], :2] + mb.vertices[border[:, 1], :2])
    assert shapely.distance(poly.exterior, shapely.points(mid)).max() < 1e-9
    # the solid is still closed; its volume differs from the planar identity only by the road's
    # linear interpolation error (< 2 mm here) over the footprints it was cut from
    refs = [reference_signed_volume(p, analytic) for p in placements]
    tm = closed_solid(build)
    expected = build.thickness_m * poly.area + sum(refs)
    footprints = sum(Polygon(p.world_footprint()).area for p in placements)
    assert abs(tm.volume - expected) < 2e-3 * footprints
    for i, p in enumerate(placements):
        vc, vb = removed_volume(mc, i, surface), removed_volume(mb, i, surface)
        assert math.isclose(vb, vc, rel_tol=0.01), (p.instance_id, vc, vb)
        # the defect's own surface, unchanged: every model vertex at surface + relative height
        dv, _ = mb.part(i)
        w = p.world_vertices()
        ref = {(float(x), float(y)): z for x, y, z in w}
        known = np.array([(float(x), float(y)) in ref for x, y in dv[:, :2]])
        assert known.sum() == len(w)
        rel = dv[known, 2] - surface.height(dv[known, :2])
        assert np.abs(rel - np.array([ref[(float(x), float(y))] for x, y in dv[known, :2]])).max() < 1e-9
    pts = grid_away_from_rims(poly, placements, 0.1, 0.02)
    zc, oc = locate(mc, pts)
    zb, ob = locate(mb, pts)
    assert np.abs(zc - zb).max() < 2e-3
    assert (oc == ob).all()


def test_straddling_defects_split_between_segments():
    """A pothole and a bump across the shared edge of two segments: each segment gets its part,
    both solids stay closed, and the parts add up to the whole defect."""
    a_poly, b_poly = box(0, 0, 6, 4), box(6, 0, 11, 4)
    seg_a, seg_b = make_segment(a_poly, "a"), make_segment(b_poly, "b")
    pot = Placement("pot", real("pothole", 8, radius_m=0.4, depth_m=0.06), 6.13, 1.17, 0.4)
    bump = Placement("bump", real("bump", 9, length_m=0.7, width_m=1.6, height_m=0.06), 5.83, 2.93, 0.3)
    placements = [pot, bump]
    surface = plane_surface((0, 0, 11, 4), 0.02, 0.05, z0=1.0)
    totals_c, totals_b = np.zeros(2), np.zeros(2)
    volume = 0.0
    for seg, poly in ((seg_a, a_poly), (seg_b, b_poly)):
        mc = CDT.merge(seg, placements, surface, RULES)
        build = BOOL.build(seg, placements, surface, RULES)
        mb = build.merged
        assert sorted(build.clipped) == [0, 1]
        for m in (mc, mb):
            assert math.isclose(xy_areas(m.vertices, m.faces).sum(), poly.area, rel_tol=1e-6)
        tm = closed_solid(build)
        volume += tm.volume - build.thickness_m * poly.area
        for i in range(2):
            vc, vb = removed_volume(mc, i, surface), removed_volume(mb, i, surface)
            assert math.isclose(vb, vc, rel_tol=0.01), (seg.id, i, vc, vb)
            totals_c[i] += vc
            totals_b[i] += vb
    ref = np.array([pot.model.volume_m3, -bump.model.volume_m3])
    assert np.allclose(totals_b, ref, rtol=1e-6) and np.allclose(totals_c, ref, rtol=1e-6)
    assert math.isclose(volume, -ref.sum(), rel_tol=1e-6)


def test_no_defects_is_the_even_road():
    seg = make_segment(box(0, 0, 5, 3))
    surface = plane_surface((0, 0, 5, 3), 0.01, 0.02, z0=0.5)
    m = BOOL.merge(seg, [], surface, RULES)
    assert (m.face_owner == -1).all() and math.isclose(xy_areas(m.vertices, m.faces).sum(), 15.0, rel_tol=1e-12)
    build = BOOL.build(seg, [], surface, RULES)
    assert math.isclose(build.solid.volume(), 0.3 * 15.0, rel_tol=1e-9)
    assert len(build.merged.faces) == len(m.faces)


def test_deep_defect_thickens_the_slab():
    seg = make_segment(box(0, 0, 4, 4))
    surface = plane_surface((0, 0, 4, 4), 0.0, 0.0, z0=0.0)
    pit, vol = ring_stack("deep", 32, [0.3, 0.5], [-0.4, -0.4, 0.0])
    build = BOOL.build(seg, [Placement("deep", pit, 2.0, 2.0, 0.0)], surface, RULES)
    assert build.thickness_m > 0.4
    assert math.isclose(build.solid.volume(), build.thickness_m * 16.0 + vol, rel_tol=1e-9)
    assert math.isclose(removed_volume(build.merged, 0, surface), -vol, rel_tol=1e-9)


def test_compose_town_with_boolean_merger(tmp_path):
    out = tmp_path / "town_boolean"
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "roadtwin_core.cli", "compose", "stages/town.usda", "-o", str(out),
                        "--defects", "10", "--merger", "boolean", "--surface", "flat"],
                       cwd=REPO, capture_output=True, text=True, timeout=300)
    elapsed = time.perf_counter() - t0
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    print(f"\ncompose --merger boolean: {elapsed:.1f} s, timings {summary['timings_s']}")
    assert summary["merger"] == "boolean"
    assert summary["defects"] == 10
    assert summary["validation"]["errors"] == 0
    assert (out / "town.usda").exists()
