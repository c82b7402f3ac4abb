"""Built-in defect types (plugin roadtwin_defects) and the README's example third-party type.

References are independent of the generators: closed-form areas and volumes, the circle
through three points, mesh topology (a disk whose only border is the loop), shapely validity.
"""
from __future__ import annotations

import dataclasses
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import LinearRing, Polygon

from roadtwin_core import DefectModel, PluginManager, RoadtwinError

TYPES = ("pothole", "depression", "bump", "rut", "manhole", "crack", "patch", "ravelling")
EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "example_plugin" / "roadtwin_speed_cushion.py"


@pytest.fixture(scope="module")
def types():
    return PluginManager().registry("defect_types")


def make(types, name, seed=0, **overrides):
    t = types[name]
    params = dataclasses.replace(t.Params(), **overrides)
    return t.generate(params, np.random.default_rng(seed), f"{name}_{seed}")


def sampled(types, name, seed):
    rng = np.random.default_rng(seed)
    t = types[name]
    return t.generate(t.sample_params(rng), rng, f"{name}_{seed}")


def assert_valid_defect(m: DefectModel, max_faces: int = 2500) -> None:
    """The DefectModel contract, checked from scratch."""
    v, f, b = m.vertices, m.faces, m.boundary
    n = len(b)
    # Faces CCW seen from +Z with positive area (own cross product, not triangle_areas).
    e1 = v[f[:, 1], :2] - v[f[:, 0], :2]
    e2 = v[f[:, 2], :2] - v[f[:, 0], :2]
    cross = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    assert (cross > 0).all()
    assert 20 <= len(f) <= max_faces
    # 2.5D: no two vertices share xy; every vertex is used.
    assert len(np.unique(np.round(v[:, :2], 9), axis=0)) == len(v)
    assert len(np.unique(f)) == len(v)
    # Boundary: a simple CCW polygon without holes, at pseudo-height 0.
    assert len(np.unique(b)) == n >= 3
    loop = v[b, :2]
    assert LinearRing(loop).is_simple
    poly = Polygon(loop)
    assert poly.is_valid and len(poly.interiors) == 0 and poly.exterior.is_ccw
    assert (v[b, 2] == 0).all()
    assert m.pseudo_height[b].all() and m.pseudo_height.sum() == n
    # Topology: a disk whose border edges are exactly the loop edges, in loop order.
    edges = np.sort(np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() <= 2
    border = {tuple(e) for e in uniq[counts == 1]}
    assert border == {tuple(sorted((int(b[i]), int(b[(i + 1) % n])))) for i in range(n)}
    assert len(v) - len(uniq) + len(f) == 1  # Euler characteristic of a disk
    # Triangles tile the footprint exactly.
    assert math.isclose(cross.sum() / 2, poly.area, rel_tol=1e-9)
    assert np.isfinite(v).all()


# ---- registration and the shared contract -------------------------------------------------

def test_all_builtin_types_registered(types):
    assert set(TYPES) <= set(types)
    for name in TYPES:
        t = types[name]
        assert t.name == name and t.description and "\n" not in t.description
        assert dataclasses.is_dataclass(t.Params)


@pytest.mark.parametrize("name", TYPES)
@pytest.mark.parametrize("seed", range(6))
def test_sampled_models_satisfy_contract(types, name, seed):
    m = sampled(types, name, seed)
    assert_valid_defect(m)
    assert m.defect_type == name and m.source == "parametric"
    assert m.params == dataclasses.asdict(types[name].sample_params(np.random.default_rng(seed)))


@pytest.mark.parametrize("name", TYPES)
def test_default_params_give_valid_model(types, name):
    assert_valid_defect(make(types, name))


@pytest.mark.parametrize("name", TYPES)
def test_same_seed_same_model(types, name):
    a, b = sampled(types, name, 7), sampled(types, name, 7)
    assert np.array_equal(a.vertices, b.vertices)
    assert np.array_equal(a.faces, b.faces)
    assert np.array_equal(a.boundary, b.boundary)


@pytest.mark.parametrize("name", ["pothole", "crack", "rut"])
def test_different_seed_different_shape(types, name):
    a, b = make(types, name, seed=1), make(types, name, seed=2)  # same params, other rng
    assert a.footprint.shape != b.footprint.shape or not np.allclose(a.footprint, b.footprint)


@pytest.mark.parametrize("name", TYPES)
def test_nan_and_out_of_range_params_name_the_parameter(types, name):
    t = types[name]
    for f in dataclasses.fields(t.Params):
        default = getattr(t.Params(), f.name)
        if isinstance(default, bool) or not isinstance(default, (int, float)):
            continue
        bad = [float("nan")] if isinstance(default, float) else []
        lo = f.metadata.get("lo")
        if lo is not None:
            bad.append(lo - 1)
        for value in bad:
            params = dataclasses.replace(t.Params(), **{f.name: value})
            with pytest.raises(RoadtwinError, match=f.name):
                t.generate(params, np.random.default_rng(0), "bad")


@pytest.mark.parametrize("name", ["pothole", "depression", "bump", "rut", "manhole", "crack", "patch"])
def test_negative_size_raises(types, name):
    size = {"pothole": "radius_m", "depression": "width_m", "bump": "length_m", "rut": "length_m",
            "manhole": "diameter_m", "crack": "width_m", "patch": "length_m"}[name]
    with pytest.raises(RoadtwinError, match=size):
        make(types, name, **{size: -0.5})


# ---- per type, against closed forms ----------------------------------------------------------

def test_manhole_is_a_regular_polygon_with_frustum_volume(types):
    d, o, ramp, frame = 0.7, -0.02, 0.015, 0.06
    m = make(types, "manhole", diameter_m=d, offset_m=o, ramp_m=ramp, frame_m=frame)
    ro = d / 2 + frame + ramp
    n = len(m.boundary)
    assert np.allclose(np.hypot(*m.footprint.T), ro, atol=1e-12)
    regular = 0.5 * n * ro * ro * math.sin(2 * math.pi / n)
    assert math.isclose(m.area_m2, regular, rel_tol=1e-9)
    assert 0 < math.pi * ro * ro - m.area_m2 <= math.pi * ro * ro * (1 - math.sin(2 * math.pi / n) / (2 * math.pi / n)) + 1e-12
    rf = d / 2 + frame
    frustum = abs(o) * math.pi * (rf * rf + rf * ramp + ramp * ramp / 3)
    assert m.volume_m3 == pytest.approx(frustum, rel=0.01)
    assert m.depth_m == pytest.approx(abs(o), abs=1e-12) and m.height_m == 0
    r = np.hypot(m.vertices[:, 0], m.vertices[:, 1])
    assert np.allclose(m.vertices[r <= d / 2, 2], o)  # flat cover
    # The band is a steep linear ramp: the steepest faces climb |offset| over ramp_m.
    v, f = m.vertices, m.faces
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    grad = np.hypot(nrm[:, 0], nrm[:, 1]) / np.abs(nrm[:, 2])
    assert grad.max() == pytest.approx(abs(o) / ramp, rel=0.05)


def test_raised_manhole(types):
    m = make(types, "manhole", offset_m=0.01)
    assert m.height_m == pytest.approx(0.01) and m.depth_m == 0


def test_depression_cosine_bell_volume(types):
    a, b, D = 1.2, 0.8, 0.03
    m = make(types, "depression", length_m=2 * a, width_m=2 * b, depth_m=D)
    assert m.volume_m3 == pytest.approx(math.pi * a * b * D * (0.5 - 2 / math.pi ** 2), rel=0.02)
    assert m.area_m2 == pytest.approx(math.pi * a * b, rel=0.005)
    assert m.depth_m == pytest.approx(D, abs=1e-12)
    assert (m.vertices[:, 2] <= 0).all()
    ext = np.ptp(m.footprint, axis=0)
    assert ext == pytest.approx([2 * a, 2 * b], rel=0.01)


@pytest.mark.parametrize("seed", range(4))
def test_pothole_depth_area_and_flat_floor(types, seed):
    t = types["pothole"]
    rng = np.random.default_rng(seed)
    p = t.sample_params(rng)
    m = t.generate(p, rng, "p")
    assert m.depth_m == pytest.approx(p.depth_m, abs=1e-12)
    assert m.height_m == 0
    # Star-shaped rim r = R(1 + sum a_k cos(...)), |a| summing to `irregularity`, stretched
    # area-preservingly: pi R^2 <= area <= pi R^2 (1 + irregularity^2 / 2) (+ discretisation).
    base = math.pi * p.radius_m ** 2
    assert 0.98 * base <= m.area_m2 <= base * (1 + p.irregularity ** 2 / 2)
    # Flat-ish floor: most of the footprint is deeper than 70 % of the depth (a cosine bell
    # would have 14 %), and steep walls: some rim face slopes more than 30 degrees.
    fz = m.vertices[m.faces, 2].mean(axis=1)
    nrm = np.cross(m.vertices[m.faces[:, 1]] - m.vertices[m.faces[:, 0]],
                   m.vertices[m.faces[:, 2]] - m.vertices[m.faces[:, 0]])
    area = 0.5 * np.abs(nrm[:, 2])
    assert area[fz < -0.7 * p.depth_m].sum() / area.sum() > 0.4
    slope = np.degrees(np.arccos(np.abs(nrm[:, 2]) / np.linalg.norm(nrm, axis=1)))
    assert slope.max() > 30


def test_pothole_rim_changes_with_seed(types):
    a, b = make(types, "pothole", seed=3), make(types, "pothole", seed=4)
    ra, rb = np.hypot(*a.footprint.T), np.hypot(*b.footprint.T)
    assert abs(ra.std() - rb.std()) > 1e-4 or abs(ra.max() - rb.max()) > 1e-3


@pytest.mark.parametrize("profile", ["circular", "parabolic", "cosine"])
def test_bump_height_and_profile(types, profile):
    L, W, H = 0.9, 3.5, 0.08
    m = make(types, "bump", length_m=L, width_m=W, height_m=H, profile=profile)
    assert m.height_m == pytest.approx(H, abs=1e-12) and m.depth_m == 0
    assert (m.vertices[:, 2] >= 0).all()
    assert np.ptp(m.footprint, axis=0) == pytest.approx([L, W], rel=0.02)
    # Middle band (away from the rounded ends): the cross-section along x.
    v = m.vertices[np.abs(m.vertices[:, 1]) < 0.3 * W / 2]
    x, z = v[:, 0], v[:, 2]
    a = L / 2
    if profile == "circular":  # circle through (-a, 0), (a, 0), (0, H): centre (0, zc)
        zc = (H * H - a * a) / (2 * H)
        assert np.allclose(np.hypot(x, z - zc), H - zc, atol=1e-6)
    elif profile == "parabolic":
        assert np.allclose(z, H * (1 - (x / a) ** 2), atol=1e-6)
    else:
        assert np.allclose(z, H * 0.5 * (1 + np.cos(np.pi * x / a)), atol=1e-6)


def test_bump_circular_too_tall_names_height(types):
    with pytest.raises(RoadtwinError, match="height_m"):
        make(types, "bump", length_m=0.1, height_m=0.08)


def test_bump_unknown_profile_names_profile(types):
    with pytest.raises(RoadtwinError, match="profile"):
        make(types, "bump", profile="square")


def test_rut_volume_and_extent(types):
    L, W, D, T = 5.0, 0.5, 0.03, 1.0
    m = make(types, "rut", length_m=L, width_m=W, depth_m=D, taper_m=T, wander_m=0.0)
    b = W / 2
    closed = D * b * (L - 2 * T) + math.pi * T * b * D * (0.5 - 2 / math.pi ** 2)
    assert m.volume_m3 == pytest.approx(closed, rel=0.02)
    assert m.depth_m == pytest.approx(D, abs=1e-12)
    assert np.ptp(m.footprint, axis=0) == pytest.approx([L, W], rel=0.01)


@pytest.mark.parametrize("seed", range(8))
def test_rut_runs_along_x(types, seed):
    m = sampled(types, "rut", seed)
    ext = np.ptp(m.footprint, axis=0)
    assert ext[0] / ext[1] > 3
    assert 1.9 <= ext[0] <= 8.1 and 0.29 <= ext[1] <= 0.9
    assert 0.01 - 1e-12 <= m.depth_m <= 0.04 + 1e-12


def test_ravelling_is_a_long_shallow_wheel_path_strip_with_the_ruts_volume(types):
    """Ravelling keeps the rut's section, so the rut's closed-form volume holds; sampled strips run
    along travel, 3-15 m long, 0.4-1.1 m wide, 1-3 cm deep (a surface course), and look like the
    exposed aggregate of a pothole's floor."""
    L, W, D, T = 9.0, 0.8, 0.02, 0.5
    m = make(types, "ravelling", length_m=L, width_m=W, depth_m=D, taper_m=T, wander_m=0.0)
    b = W / 2
    closed = D * b * (L - 2 * T) + math.pi * T * b * D * (0.5 - 2 / math.pi ** 2)
    assert m.volume_m3 == pytest.approx(closed, rel=0.02) and m.defect_type == "ravelling"
    assert np.ptp(m.footprint, axis=0) == pytest.approx([L, W], rel=0.01)
    for seed in range(8):
        s = sampled(types, "ravelling", seed)
        ext = np.ptp(s.footprint, axis=0)
        assert ext[0] / ext[1] > 2.5 and 2.9 <= ext[0] <= 15.1 and 0.39 <= ext[1] <= 1.35
        assert 0.01 - 1e-12 <= s.depth_m <= 0.03 + 1e-12
    assert types["ravelling"].material == types["pothole"].material == "pothole"   # lost surface course


def test_rut_taper_longer_than_half_names_taper(types):
    with pytest.raises(RoadtwinError, match="taper_m"):
        make(types, "rut", length_m=2.0, taper_m=1.5)


@pytest.mark.parametrize("seed", range(25))
def test_crack_network_is_one_hole_free_v_groove(types, seed):
    # Many long, twisty branches: the hardest case for staying a tree.
    m = make(types, "crack", seed=seed, branches=8, tortuosity=0.8, extent_m=1.5, width_m=0.02,
             depth_m=0.012)
    assert_valid_defect(m)
    assert m.depth_m == pytest.approx(0.012, abs=1e-12)
    assert (m.vertices[:, 2] <= 0).all()
    # V cross-section: mean depth over the footprint is half the depth (ends/junctions aside).
    assert m.volume_m3 / (m.area_m2 * 0.012) == pytest.approx(0.5, abs=0.08)
    # Narrow groove: area ~ width x length, so area / extent^2 stays small.
    assert m.area_m2 < 0.2 * np.ptp(m.footprint, axis=0).max() ** 2


def _inset_area_integral(a: float, b: float, c: float, t: float) -> float:
    """integral_0^t A(s) ds for a 2a x 2b rectangle with corner radius c inset by s:
    A(s) = 4 (a - s)(b - s) - (4 - pi) max(c - s, 0)^2 (an inset rounded corner keeps its centre)."""
    m = min(c, t)
    return 4 * (a * b * t - (a + b) * t * t / 2 + t ** 3 / 3) - (4 - math.pi) * (c * c * m - c * m * m + m ** 3 / 3)


@pytest.mark.parametrize("corner", [0.0, 0.02, 0.12])
def test_raised_patch_area_volume_and_flat_top(types, corner):
    L, W, H, t = 2.0, 1.2, 0.008, 0.04
    m = make(types, "patch", length_m=L, width_m=W, height_m=H, bevel_m=t, corner_m=corner)
    a, b = L / 2, W / 2
    exact = L * W - (4 - math.pi) * corner ** 2
    assert m.area_m2 == pytest.approx(exact, rel=2e-4) and m.area_m2 <= exact + 1e-12  # inscribed arcs
    assert np.ptp(m.footprint, axis=0) == pytest.approx([L, W], abs=1e-12)
    # Layer-cake volume: z = H min(d / t, 1) with d the distance to the edge.
    assert m.volume_m3 == pytest.approx(H / t * _inset_area_integral(a, b, corner, t), rel=2e-3)
    assert m.height_m == pytest.approx(H, abs=1e-12) and m.depth_m == 0
    v = m.vertices
    ax, ay, e = np.abs(v[:, 0]), np.abs(v[:, 1]), max(t, corner) + 1e-9  # a cross inside the inset
    inner = ((ax <= a - t - 1e-9) & (ay <= b - e)) | ((ax <= a - e) & (ay <= b - t - 1e-9))
    assert inner.sum() >= 4 and np.allclose(v[inner, 2], H)  # flat top
    assert (v[:, 2] >= 0).all() and (v[:, 2] <= H + 1e-12).all()
    # Along the straight sides (away from the corners) the bevel is a plane climbing H over bevel_m.
    f = m.faces
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    grad = np.hypot(nrm[:, 0], nrm[:, 1]) / np.abs(nrm[:, 2])
    cen = v[f].mean(axis=1)
    side = (np.abs(cen[:, 0]) < a - 3 * t - corner) & (np.abs(cen[:, 1]) > b - t)
    assert side.sum() >= 10 and np.allclose(grad[side], H / t, rtol=1e-6)


def test_flush_patch_is_flat_and_outline_is_dense(types):
    m = make(types, "patch", length_m=2.5, width_m=0.6, height_m=0.0, corner_m=0.0)
    assert_valid_defect(m)
    assert (m.vertices[:, 2] == 0).all() and m.volume_m3 == 0
    assert m.area_m2 == pytest.approx(2.5 * 0.6, rel=1e-12)  # sharp rectangle, exactly
    loop = m.footprint
    edge = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
    assert edge.max() <= 0.04 + 1e-12  # the merger needs an outline densified at a few cm


def test_sampled_patches_are_realistic(types):
    for seed in range(20):
        p = types["patch"].sample_params(np.random.default_rng(seed))
        assert 0.4 <= p.length_m <= 3.0 and 0.4 <= p.width_m <= 3.0
        assert 0.0 <= p.height_m <= 0.010


@pytest.mark.parametrize("override, param", [({"corner_m": 0.6}, "corner_m"), ({"bevel_m": 0.4}, "bevel_m")])
def test_patch_inconsistent_sizes_name_the_parameter(types, override, param):
    with pytest.raises(RoadtwinError, match=param):
        make(types, "patch", length_m=1.0, width_m=0.8, **override)


def test_generation_is_fast(types):
    import time

    t0 = time.perf_counter()
    for name in TYPES:
        for seed in range(5):
            sampled(types, name, seed)
    assert time.perf_counter() - t0 < 5.0  # ~5 ms a model; a town needs hundreds


# ---- the README's example third-party plugin ------------------------------------------------

@pytest.fixture(scope="module")
def cushion_module():
    spec = importlib.util.spec_from_file_location("roadtwin_speed_cushion", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while building
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def test_example_plugin_registers_and_generates(cushion_module):
    pm = PluginManager(load_entry_points=False)
    pm.register(cushion_module, name="speed_cushion")
    t = pm.get("defect_types", "speed_cushion")
    assert set(pm.registry("defect_types")) == {"speed_cushion"}
    p = t.Params(length_m=3.0, width_m=1.8, height_m=0.07, ramp_m=0.6, side_m=0.25)
    m = t.generate(p, np.random.default_rng(0), "cushion")
    assert_valid_defect(m)
    assert m.defect_type == "speed_cushion"
    assert m.height_m == pytest.approx(0.07) and m.depth_m == 0
    # Prismatoid (level sets are rectangles shrinking linearly): Simpson's rule is exact.
    L, W, H = 3.0, 1.8, 0.07
    lt, wt = L - 2 * 0.6, W - 2 * 0.25
    assert m.volume_m3 == pytest.approx(H / 6 * (L * W + lt * wt + (L + lt) * (W + wt)), rel=1e-9)
    assert m.area_m2 == pytest.approx(L * W, rel=1e-12)
    assert_valid_defect(t.generate(t.sample_params(np.random.default_rng(1)), np.random.default_rng(1), "c"))
    with pytest.raises(RoadtwinError, match="height_m"):
        t.generate(t.Params(height_m=float("nan")), np.random.default_rng(0), "bad")
