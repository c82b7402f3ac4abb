"""A map's own objects (:class:`~roadtwin_core.model.MapObject`: OpenDRIVE objects and signals)
as props: each becomes an instance of the nearest procedural prototype, scaled to its size.

Which prototype (:func:`prototype_for`): by the object's type (:data:`TYPE_PROTOTYPES`), refined
by its subtype / name (a conifer, tall grass, a fence, a low pole = a delineator); a type the map
leaves open (OpenDRIVE 1.4 "-1", "none", "") by keywords of its name (CARLA writes its speed-limit
signs as type "-1" named "Speed_30"). Signals: a dynamic one is a traffic light, any other a sign
post. Cars take one of three paints, chosen by a hash of the object's id (same map, same bytes).
Anything else (crosswalk, parkingSpace, building, pedestrian, bike, patch ...) is skipped and
counted by type: ``Props.map_objects["skipped"]``.

Scale: vehicles per axis to length / width / height where given; trees and shrubs uniformly to
the height (else the width); poles and street lamps in z to the height; barriers and fences in x
to the length (their sections run from x = 0, so they are shifted to be centred on the object);
signs keep their size (the map's width/height are the plate's, the prototype has its own post).
Each scale is clamped to [0.1, 10]. Props stand on the compose surface at the object's x, y (the
map's z, zOffset included, is kept in the layout but not used: the prototypes model their posts).

Where: the map is trusted (its objects are placed before the seeded rules, ignore their spacing
and are added to the occupancy grid, so the rules fill around them), with one exception: a
non-vehicle whose footprint reaches onto the driving surface (segments of
:data:`DRIVING_KINDS`, 2 cm in) is skipped and counted (``on_driving_surface``), since props never
stand on the road. Map vehicles form the instancer ``MapVehicles`` (place ``lane``: cameras keep
clear of them), everything else ``MapObjects`` (place ``map``); both of rule ``map_objects``.
They come with the props layer: ``compose --props none`` leaves them out too.
"""
from __future__ import annotations

import math
import zlib

import numpy as np
import shapely

from ..model import MapObject, RoadSegment
from .prop_shapes import make_prototype, posed_footprints

DRIVING_KINDS = ("driving", "junction", "bidirectional", "entry", "exit", "onRamp", "offRamp", "connectingRamp",
                 "stop")
RULE = "map_objects"
CARS = ("car_grey", "car_red", "car_white")
TYPE_PROTOTYPES = {
    "tree": "tree_round", "vegetation": "shrub", "pole": "utility_pole", "streetLamp": "street_lamp",
    "barrier": "guardrail", "railing": "fence", "car": "car", "van": "car", "bus": "bus", "trailer": "truck",
    "truck": "truck", "tram": "bus", "signal": "sign_rect",
}
UNSPECIFIED_TYPES = ("", "-1", "none")
NAME_KEYWORDS = (("speed", "sign_rect"), ("sign", "sign_rect"), ("stop", "sign_rect"), ("yield", "sign_rect"),
                 ("light", "traffic_light"), ("lamp", "street_lamp"), ("tree", "tree_round"), ("bush", "shrub"),
                 ("guardrail", "guardrail"), ("fence", "fence"), ("pole", "utility_pole"))
_SCALE_LIMITS = (0.1, 10.0)


def prototype_for(obj: MapObject) -> str | None:
    """The prototype name a map object becomes, or None (skipped)."""
    words = f"{obj.subtype} {obj.name}".lower()
    if obj.kind == "signal":
        return "traffic_light" if obj.dynamic else "sign_rect"
    kind = obj.type
    if kind.lower() in UNSPECIFIED_TYPES:
        return next((proto for key, proto in NAME_KEYWORDS if key in obj.name.lower()), None)
    proto = TYPE_PROTOTYPES.get(kind)
    if proto == "car":
        return CARS[zlib.crc32(obj.id.encode()) % len(CARS)]
    if proto == "tree_round" and any(k in words for k in ("conifer", "pine", "fir", "spruce", "needle")):
        return "tree_conifer"
    if proto == "shrub" and "grass" in words:
        return "grass_tuft"
    if proto == "guardrail" and any(k in words for k in ("fence", "railing")):
        return "fence"
    if proto == "utility_pole" and 0 < obj.size[2] <= 1.5:
        return "km_post"
    return proto


def _bbox(proto) -> np.ndarray:
    v = np.concatenate([p.vertices for p in proto.parts])
    return v.max(axis=0) - v.min(axis=0)


def scale_for(obj: MapObject, proto_name: str) -> np.ndarray:
    """Per-axis scale of the prototype that gives it the object's size (see the module docstring)."""
    proto = make_prototype(proto_name)
    length, width, height = obj.size
    dims = _bbox(proto)
    s = np.ones(3)
    if proto.label == "vehicle":
        s = np.array([length / dims[0] if length > 0 else 1.0, width / dims[1] if width > 0 else 1.0,
                      height / dims[2] if height > 0 else 1.0])
    elif proto.label == "vegetation":
        s[:] = height / dims[2] if height > 0 else (max(length, width) / max(dims[0], dims[1])
                                                     if max(length, width) > 0 else 1.0)
    elif proto.label == "pole" and height > 0:
        s[2] = height / dims[2]
    elif proto.label in ("guardrail", "fence"):
        fp = proto.footprint
        s[0] = length / (fp[2] - fp[0]) if length > 0 else 1.0
        s[2] = height / dims[2] if height > 0 else 1.0
    return np.clip(s, *_SCALE_LIMITS)


def driving_surface(segments: list[RoadSegment]):
    polys = [s.polygon() for s in segments if s.kind in DRIVING_KINDS]
    surface = shapely.union_all(polys).buffer(-0.02) if polys else shapely.Polygon()
    shapely.prepare(surface)
    return surface


def map_instances(objects: list[MapObject], segments: list[RoadSegment]):
    """The map objects that become props: ``(rows, counts)`` with rows (object, prototype, xy,
    yaw, scale, is_vehicle) in map order and counts the summary (placed, skipped, on the driving
    surface, each by type)."""
    skipped: dict[str, int] = {}
    on_road: dict[str, int] = {}
    chosen = [(o, prototype_for(o)) for o in objects]
    for o, p in chosen:
        if p is None:
            skipped[o.type or "none"] = skipped.get(o.type or "none", 0) + 1
    chosen = [(o, p) for o, p in chosen if p is not None]
    rows = []
    for o, name in chosen:
        proto = make_prototype(name)
        yaw, scale = o.hpr[0], scale_for(o, name)
        xy = np.array(o.position[:2], np.float64)
        if proto.label in ("guardrail", "fence"):      # sections run from x = 0: centre them
            half = 0.5 * (proto.footprint[2] - proto.footprint[0]) * scale[0]
            xy = xy - half * np.array([math.cos(yaw), math.sin(yaw)])
        rows.append((o, name, xy, yaw, scale, proto.label == "vehicle"))
    standing = [r for r in rows if not r[5]]
    if standing:       # one vectorised test: a map's repeats run to thousands of objects
        protos = [make_prototype(r[1]) for r in standing]
        fps = posed_footprints(protos, np.arange(len(protos)), np.array([r[2] for r in standing]),
                               np.array([r[3] for r in standing]), np.array([r[4] for r in standing]))
        hit = shapely.intersects(driving_surface(segments), fps)
        for r in (r for r, h in zip(standing, hit) if h):
            key = f"signal:{r[0].type}" if r[0].kind == "signal" else (r[0].type or "none")
            on_road[key] = on_road.get(key, 0) + 1
        dropped = {id(r) for r, h in zip(standing, hit) if h}
        rows = [r for r in rows if id(r) not in dropped]
    counts = {"placed": len(rows), "skipped": dict(sorted(skipped.items())),
              "on_driving_surface": dict(sorted(on_road.items()))}
    return rows, counts


def quat_ypr(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w, x, y, z) of q_z(yaw) * q_y(pitch) * q_x(roll) (OpenDRIVE's heading,
    pitch, roll order)."""
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    return np.column_stack([cy * cp * cr + sy * sp * sr, cy * cp * sr - sy * sp * cr,
                            cy * sp * cr + sy * cp * sr, sy * cp * cr - cy * sp * sr])
