"""The roadside world (layers/props.usda): placement rules, the layer, and reading it back.

Fast, CPU only, no compose: props are placed on the sample layout with a flat height, written
with ``write_props`` and read back with ``load_town``. The pole's shadow through the renderer is
tests/plugins/test_props_shadow.py; compose with props, tests/apps/test_compose_props.py.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
import shapely
from pxr import Sdf, Usd, UsdGeom, UsdSemantics

from roadtwin_core import MapObject
from roadtwin_core.errors import RoadtwinError
from roadtwin_core.render import GroundSampler, build_render_mesh
from roadtwin_core.render.cameras import KeepOut, lane_keep_out, sample_lane_poses
from roadtwin_core.render.classmap import load_class_map
from roadtwin_core.render.view_sampler import DefectTargets, chain_lanes, sample_views
from roadtwin_core.town.prop_shapes import PROP_LABELS, PROTOTYPES, make_prototype
from roadtwin_core.town.props import DEFAULT_RULES, PropRule, Props, load_prop_rules, paved_surface, place_props
from roadtwin_core.usd.layout_io import read_layout
from roadtwin_core.usd.props import write_props
from roadtwin_core.usd.stage import new_layer
from roadtwin_core.usd.town_reader import load_town
from roadtwin_core.usd.validate import validate_stage

REPO = Path(__file__).resolve().parents[2]
TOWN = REPO / "stages" / "town.usda"


def flat(xy):
    return np.zeros(len(xy))


@pytest.fixture(scope="module")
def layout():
    return read_layout(TOWN)


@pytest.fixture(scope="module")
def props(layout):
    return place_props(layout.segments, DEFAULT_RULES, flat, 7, str(TOWN))


@pytest.fixture(scope="module")
def props_stage(props, tmp_path_factory) -> Path:
    """The props layer over the sample layout: ``town.usda`` sublayering props.usda and the layout."""
    tmp = tmp_path_factory.mktemp("props")
    (tmp / "layers").mkdir()
    write_props(tmp, "Town", "test", props)
    (tmp / "layout").mkdir()
    (tmp / "layout/town.usda").write_bytes(TOWN.read_bytes())
    root = new_layer(tmp / "town.usda", "Town", "test")
    root.subLayerPaths = ["./layers/props.usda", "./layout/town.usda"]
    Sdf.CreatePrimInLayer(root, Sdf.Path("/Town"))
    root.Save()
    return tmp / "town.usda"


def _quat_rotate(q, v):
    w, u = q[:, None, :1], q[:, None, 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def test_props_never_stand_on_the_road(layout, props):
    """Every prop but the vehicles: the convex hull of its posed ground parts (trunk, posts,
    sections) lies off the union of the paved segments (computed here, unsimplified; 3 cm for
    the placer's 2 cm outline simplification). Every default rule but the fences (6 m out: the
    sample town's blocks leave them no room) placed something."""
    paved = shapely.union_all([s.polygon() for s in layout.segments if s.kind != "verge"]).buffer(-0.03)
    shapely.prepare(paved)
    assert set(props.by_rule()) >= {r.name for r in DEFAULT_RULES} - {"fences"}
    checked = 0
    for g in props.groups:
        for k, proto in enumerate(g.prototypes):
            if proto.label in ("vehicle", "terrain") or g.name == "Wires":
                continue
            ground = np.concatenate([p.vertices for p in proto.parts if p.ground])
            ground = ground[ground[:, 2] < 0.5]
            mine = g.proto_indices == k
            pts = _quat_rotate(g.orientations[mine], ground[None] * g.scales[mine][:, None, :])
            pts = pts + g.positions[mine][:, None, :]
            hulls = shapely.convex_hull(shapely.multipoints(pts[..., :2]))
            on = shapely.intersects(paved, hulls)
            assert not on.any(), f"{g.name}/{proto.name} at {g.positions[mine][on][:3, :2]} stands on the road"
            checked += int(mine.sum())
    assert checked > 500


def test_lane_vehicles_stand_in_driving_lanes(layout, props):
    driving = shapely.union_all([s.polygon() for s in layout.segments if s.kind in ("driving", "junction")])
    lane = [g for g in props.groups if g.rule == "lane_vehicles"]
    assert lane and all(g.place == "lane" for g in lane)
    assert all(shapely.contains_xy(driving.buffer(0.05), g.positions[:, 0], g.positions[:, 1]).all() for g in lane)


def test_lane_vehicles_leave_the_defects_visible(layout, props):
    """Discs already taken (compose passes the defects) keep every prop's clearance off them: a
    car stopped in the lane never covers a pothole; it moves along its lane to a clear spot.
    Here: a disc where every other lane car stood."""
    cars = np.concatenate([g.positions for g in props.groups if g.rule == "lane_vehicles"])
    taken = np.column_stack([cars[::2, :2], np.full(len(cars[::2]), 0.8)])
    again = place_props(layout.segments, DEFAULT_RULES, flat, 7, str(TOWN), taken=taken)
    kept = np.concatenate([g.positions for g in again.groups if g.rule == "lane_vehicles"])
    clearance = make_prototype("car_red").clearance_m
    d = np.linalg.norm(kept[:, None, :2] - taken[None, :, :2], axis=2)
    assert len(kept) >= len(cars) // 2 and (d >= clearance + 0.8 - 1e-9).all()
    moved = np.linalg.norm(kept[:, None, :2] - cars[None, ::2, :2], axis=2).min(axis=1)
    assert (moved > 2.0).all()


def _write(tmp: Path, props: Props) -> tuple[bytes, bytes]:
    (tmp / "layers").mkdir(parents=True)
    write_props(tmp, "Town", "test", props)
    return (tmp / "layers/props.usda").read_bytes(), (tmp / "layers/props.geom.usdc").read_bytes()


def test_same_seed_same_bytes(layout, props, tmp_path):
    again = place_props(layout.segments, DEFAULT_RULES, flat, 7, str(TOWN))
    other = place_props(layout.segments, DEFAULT_RULES, flat, 8, str(TOWN))
    a, b, c = _write(tmp_path / "a", props), _write(tmp_path / "b", again), _write(tmp_path / "c", other)
    assert a == b
    assert a[1] != c[1]


def test_props_layer_validates_and_is_instanced(props, props_stage):
    """The props layer over the sample layout passes pxr.UsdValidation; geometry is stored once
    per prototype (instancers, not copies); prototypes carry LabelsAPI class labels."""
    errors = [f for f in validate_stage(props_stage) if f.severity == "Error"]
    assert not errors, errors[:3]
    stage = Usd.Stage.Open(str(props_stage))
    instancers = [p for p in stage.Traverse() if p.IsA(UsdGeom.PointInstancer)]
    assert len(instancers) >= 10
    n_instances = sum(len(UsdGeom.PointInstancer(p).GetProtoIndicesAttr().Get()) for p in instancers)
    n_meshes = sum(1 for p in Usd.PrimRange(stage.GetPrimAtPath("/Town/Props")) if p.IsA(UsdGeom.Mesh))
    assert n_instances == props.count and n_meshes < 80 < n_instances
    labels = set()
    for p in instancers:
        for target in UsdGeom.PointInstancer(p).GetPrototypesRel().GetTargets():
            api = UsdSemantics.LabelsAPI(stage.GetPrimAtPath(target), "class")
            labels.add(str(api.GetLabelsAttr().Get()[0]))
    assert labels >= {"vegetation", "pole", "sign", "vehicle", "terrain", "guardrail"}
    assert labels <= set(PROP_LABELS)


def test_load_town_expands_the_instancers(props, props_stage):
    """Each instance is drawn: the expanded triangles are the prototypes' triangles times their
    instances (plus the terrain), and each instancer's positions come back (float32 in the crate)."""
    town = load_town(props_stage, looks=True)
    assert {m.kind for m in town.props} <= set(PROP_LABELS)
    want = sum(sum(p.triangles() for p in np.asarray(g.prototypes, dtype=object)[g.proto_indices]) for g in props.groups)
    assert sum(len(m.faces) for m in town.props) == want + len(props.ground[1])
    assert all(m.material is not None for m in town.props)
    by_path = {i.path: i for i in town.instances}
    for g in props.groups:
        got = by_path[f"/Town/Props/{g.name}"]
        assert got.place == g.place
        np.testing.assert_allclose(got.positions, g.positions, atol=1e-3)
        assert (got.labels == np.array([g.prototypes[k].label for k in g.proto_indices])).all()
    mesh = build_render_mesh(town)
    assert set(PROP_LABELS) - {"fence"} <= set(mesh.classes)


def test_ground_sampler_leaves_props_out(props_stage):
    """Cameras stand on the road, not on a car's roof or a tree's crown: the ground sampler reads
    the height of the road faces only (here: the layout's flat road, z = 0, under a lane car)."""
    town = load_town(props_stage)
    cars = [i for i in town.instances if i.place == "lane"][0].positions
    ground = GroundSampler(build_render_mesh(town))
    assert np.allclose(ground(cars[:, :2]), 0.0, atol=1e-6)


def test_cameras_keep_clear_of_lane_vehicles(layout, props_stage):
    """The view sampler and the random lane poses never put a camera on or just behind a vehicle
    standing in the lane (a disc about each, its plan radius + 3.5 m)."""
    town = load_town(props_stage)
    keep = lane_keep_out(town)
    assert len(keep.xy) >= 2 and (keep.radius > 2.0).all()
    lanes = chain_lanes([l for l in _lanes(layout)])
    ground = GroundSampler(build_render_mesh(town))
    none = DefectTargets([], [], np.zeros((0, 2)))
    views = sample_views(lanes, none, ground, 300, share=0.0, seed=5, keep_out=keep)
    xy = np.array([v.cam_to_world[:2, 3] for v in views])
    d = np.linalg.norm(xy[:, None, :] - keep.xy[None], axis=2)
    assert (d >= keep.radius + keep.margin_m).all()
    free = sample_views(lanes, none, ground, 300, share=0.0, seed=5)   # without: some stand there
    d_free = np.linalg.norm(np.array([v.cam_to_world[:2, 3] for v in free])[:, None] - keep.xy[None], axis=2)
    assert (d_free < keep.radius + keep.margin_m).any()
    poses = sample_lane_poses(lanes, 300, np.random.default_rng(2), ground, keep_out=keep)
    d = np.linalg.norm(np.array([p[:2, 3] for p in poses])[:, None] - keep.xy[None], axis=2)
    assert (d >= keep.radius + keep.margin_m).all()
    assert KeepOut(np.zeros((0, 2)), np.zeros(0)).clear(np.zeros(2))


def _lanes(layout):
    from roadtwin_core.render import Lane

    return [Lane(s.id, np.asarray(s.centerline, float)) for s in layout.segments
            if s.kind == "driving" and s.centerline is not None and len(s.centerline) >= 2]


def test_road_defects_br_classmap_names_every_prop_label():
    """The survey dataset's class map says what each prop label becomes (background)."""
    path = REPO / "roadtwin_core/render/classmaps/road_defects_br.toml"
    data = tomllib.loads(path.read_text())
    assert set(PROP_LABELS) <= set(data["map"]["background"]) and set(PROP_LABELS) <= set(data["optional"])
    load_class_map("road_defects_br")
    assert {make_prototype(p).label for p in PROTOTYPES} == set(PROP_LABELS)


def test_bad_rule_values_are_named(layout):
    with pytest.raises(RoadtwinError, match="unknown prototype 'tree_palm'"):
        place_props(layout.segments, (PropRule("x", "X", {"tree_palm": 1.0}),), flat, 0, "t")
    with pytest.raises(RoadtwinError, match="only vehicles may stand in a lane"):
        place_props(layout.segments, (PropRule("x", "X", {"tree_round": 1.0}, place="lane"),), flat, 0, "t")
    with pytest.raises(RoadtwinError, match="offset_m must be"):
        place_props(layout.segments, (PropRule("x", "X", {"tree_round": 1.0}, offset_m=(5.0, 2.0)),), flat, 0, "t")


def test_rule_that_fits_nothing_says_why(layout):
    rule = PropRule("giant_poles", "Poles", {"utility_pole": 1.0}, spacing_m=100000.0)
    with pytest.raises(RoadtwinError, match=r"props rule 'giant_poles' fits nothing: spacing 100000 m is longer"):
        place_props(layout.segments, (rule,), flat, 0, "t")


@pytest.mark.parametrize("text, message", [
    (None, "props rules file not found"),
    ("[[rule]\n", "not a TOML props rules file"),
    ('colour = "red"\n', "unknown key 'colour'"),
    ('[[rule]]\nname = "a"\ngroup = "A"\nprototypes = {shrub = 1}\nheight = 2\n', "rule 'a': unknown key 'height'"),
    ('[[rule]]\nname = "a"\nprototypes = {shrub = 1}\n', "rule 'a': missing 'group'"),
    ('[[rule]]\nname = "a"\ngroup = "A"\nprototypes = {shrub = 1}\noffset_m = [1]\n', "offset_m needs two numbers"),
    ('[[rule]]\nname = "a"\ngroup = 5\nprototypes = {shrub = 1}\n', "group must be a string, got 5"),
    ('[[rule]]\nname = "a"\ngroup = "Terrain"\nprototypes = {shrub = 1}\n', "group 'Terrain' is taken"),
    ('defaults = "yes"\n', "defaults must be true or false"),
    ('defaults = true\n', None),
    ("", "no \\[\\[rule\\]\\] tables"),
])
def test_rules_file_errors_are_one_line(tmp_path, text, message):
    path = tmp_path / "rules.toml"
    if text is not None:
        path.write_text(text)
    if message is None:
        assert load_prop_rules(path) == DEFAULT_RULES
        return
    with pytest.raises(RoadtwinError, match=message) as err:
        load_prop_rules(path)
    assert "\n" not in str(err.value)


def test_a_folder_is_not_a_rules_file(tmp_path):
    with pytest.raises(RoadtwinError, match="cannot read the props rules file"):
        load_prop_rules(tmp_path)


def test_groups_of_one_name_become_two_instancers(layout, tmp_path):
    """Two rules naming one group (or two pole rules, each with its Wires) get one instancer each."""
    rules = (PropRule("a", "Trees", {"tree_round": 1.0}, offset_m=(4, 8), spacing_m=10.0, density_per_km=60.0),
             PropRule("b", "Trees", {"tree_conifer": 1.0}, offset_m=(9, 14), spacing_m=10.0, density_per_km=60.0))
    props = place_props(layout.segments, rules, flat, 1, "t", ground=False)
    assert [g.name for g in props.groups] == ["Trees", "Trees_1"]
    _write(tmp_path, props)
    stage = Usd.Stage.Open(str(tmp_path / "layers/props.usda"))
    assert all(stage.GetPrimAtPath(f"/Town/Props/{n}").IsA(UsdGeom.PointInstancer) for n in ("Trees", "Trees_1"))


def test_rules_file_adds_to_the_defaults(tmp_path):
    path = tmp_path / "rules.toml"
    path.write_text('defaults = true\n[[rule]]\nname = "trees"\ngroup = "Trees"\nprototypes = {tree_conifer = 1}\n'
                    'offset_m = [5, 9]\nspacing_m = 12\n')
    rules = load_prop_rules(path)
    assert [r.name for r in rules] == [r.name for r in DEFAULT_RULES if r.name != "trees"] + ["trees"]
    assert rules[-1].prototypes == {"tree_conifer": 1.0} and rules[-1].offset_m == (5.0, 9.0)


def test_seeded_rules_keep_clear_of_map_objects(layout):
    """Map objects (an OpenDRIVE map's trees) are placed first and the rules fill around them: no
    rule-placed prop's clearance disc overlaps a map tree's (discs computed here from the
    prototypes' clearance and the instance scales). Without the map trees the same rules do put
    props there, so the check can fail."""
    ring = paved_surface(layout.segments).buffer(6.0).exterior
    spots = [ring.interpolate(d) for d in np.arange(0.0, ring.length, 25.0)]
    trees = [MapObject(f"t{k}", "object", "tree", (p.x, p.y, 0.0), size=(0, 0, 8.0)) for k, p in enumerate(spots)]
    rules = tuple(r for r in DEFAULT_RULES if r.place in ("roadside", "chain"))
    tree = make_prototype("tree_round")
    height = np.ptp(np.concatenate([p.vertices for p in tree.parts])[:, 2])
    r_tree = tree.clearance_m * 8.0 / height                             # scaled to the map's 8 m

    def overlaps(props):
        hits = 0
        for g in props.groups:
            if g.rule == "map_objects" or g.name == "Wires" or g.place != "roadside":   # chains: other discs
                continue
            radii = np.array([p.clearance_m for p in g.prototypes])[g.proto_indices] * g.scales[:, :2].max(axis=1)
            for tree in trees:
                d = np.hypot(g.positions[:, 0] - tree.position[0], g.positions[:, 1] - tree.position[1])
                hits += int((d < 0.99 * (radii + r_tree)).sum())
        return hits

    with_map = place_props(layout.segments, rules, flat, 3, "t", ground=False, map_objects=trees)
    assert with_map.map_objects["placed"] == len(trees) > 20
    assert overlaps(with_map) == 0
    assert overlaps(place_props(layout.segments, rules, flat, 3, "t", ground=False)) > 0
