"""The roadside world: seeded rules place instances of procedural prototypes beside the road.

What it places (``DEFAULT_RULES``; a TOML file of ``[[rule]]`` tables replaces them, see
:func:`load_prop_rules`): trees, shrubs, tall-grass tufts, utility poles with wires between
neighbours, sign posts, km posts, guardrail and fence runs, parked cars / trucks / buses beside
the road, cars stopped at the kerb side of driving lanes, and distant hills; plus one terrain
mesh around the whole town (slightly below the road, so the verge and the horizon are ground, not
sky; cut away under the paved surface so that no deep defect shows it, :mod:`.terrain`).

Where: the *paved surface* is the union of the layout's segments of every kind but
``verge`` (props may stand on a verge: it is grass). A ``roadside`` rule walks the outline of
the paved surface grown by the rule's offset (so every candidate lies ``offset_m`` from the
nearest paved edge), one candidate per ``spacing_m`` of outline with seeded jitter, keeps a
fraction ``density_per_km * spacing_m / 1000`` of them, and rejects a candidate whose footprint
(the prototype's ground parts, posed) touches the paved surface or comes nearer than the
clearance of an accepted prop. ``chain`` rules (guardrails, fences) lay runs of sections end to
end along the outline instead. ``lane`` rules (vehicles only) put instances on driving lanes at
their right edge, along travel. ``far`` rules place scaled prototypes (hills) ``offset_m`` out.

A rule that places nothing (a spacing longer than every outline, an offset that leaves no room)
is bad input: one :class:`RoadtwinError` line naming the rule, before anything is written.
Randomness depends only on (seed, rule index): same seed, same props.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry.polygon import orient

from ..errors import RoadtwinError
from ..model import MapObject, RoadSegment
from .map_props import RULE as MAP_RULE, map_instances, quat_ypr
from .prop_shapes import PROTOTYPES, Prototype, make_prototype
from .prop_shapes import posed_footprints as _footprints
from .terrain import terrain_mesh

UNPAVED_KINDS = ("verge",)
PLACES = ("roadside", "chain", "lane", "far")
YAWS = ("along", "random", "face_traffic")
RESERVED_GROUPS = ("Terrain", "Looks")   # other children of /<root>/Props
LANE_SHIFTS_M = np.array([0.0, 3.0, -3.0, 6.0, -6.0, 9.0, -9.0, 12.0])   # where a lane vehicle may move to


@dataclass(frozen=True)
class PropRule:
    name: str
    group: str                                  # PointInstancer name under /<root>/Props
    prototypes: dict[str, float]                # prototype -> weight
    place: str = "roadside"
    offset_m: tuple[float, float] = (2.0, 6.0)  # from the paved edge (lane: from the lane's right edge)
    spacing_m: float = 20.0
    density_per_km: float = 50.0                # instances per km of outline (at most 1000 / spacing)
    scale: tuple[float, float] = (0.85, 1.15)
    height_scale: tuple[float, float] = (1.0, 1.0)   # extra factor on z (far hills: their height)
    yaw: str = "random"
    run_m: tuple[float, float] = (40.0, 120.0)  # chain rules: length of one run
    wires: bool = False                         # poles: wires between neighbours along the outline

    def check(self, owner: str) -> "PropRule":
        where = f"{owner}: props rule {self.name!r}"
        if not self.prototypes:
            raise RoadtwinError(f"{where}: names no prototypes")
        for p, w in self.prototypes.items():
            if p not in PROTOTYPES:
                raise RoadtwinError(f"{where}: unknown prototype {p!r} (known: {', '.join(sorted(PROTOTYPES))})")
            if not (math.isfinite(w) and w >= 0):
                raise RoadtwinError(f"{where}: weight of {p!r} must be >= 0, got {w}")
        if sum(self.prototypes.values()) <= 0:
            raise RoadtwinError(f"{where}: all prototype weights are zero")
        if self.place not in PLACES:
            raise RoadtwinError(f"{where}: place must be one of {', '.join(PLACES)}, got {self.place!r}")
        if self.yaw not in YAWS:
            raise RoadtwinError(f"{where}: yaw must be one of {', '.join(YAWS)}, got {self.yaw!r}")
        for name in ("offset_m", "scale", "height_scale", "run_m"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
                raise RoadtwinError(f"{where}: {name} must be [lo, hi] with 0 <= lo <= hi, got {[lo, hi]}")
        for name in ("spacing_m", "density_per_km"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise RoadtwinError(f"{where}: {name} must be a positive number, got {v}")
        if self.scale[0] <= 0 or self.height_scale[0] <= 0:
            raise RoadtwinError(f"{where}: scales must be > 0")
        if self.place == "lane" and any(make_prototype(p).label != "vehicle" for p in self.prototypes):
            raise RoadtwinError(f"{where}: only vehicles may stand in a lane")
        if not self.group.isidentifier():
            raise RoadtwinError(f"{where}: group {self.group!r} is not a valid prim name")
        if self.group in RESERVED_GROUPS:
            raise RoadtwinError(f"{where}: group {self.group!r} is taken (/<root>/Props/{self.group} is the "
                                f"{'terrain mesh' if self.group == 'Terrain' else 'materials scope'})")
        return self


DEFAULT_RULES: tuple[PropRule, ...] = (   # placed in this order: later rules fill around earlier ones
    PropRule("lane_vehicles", "LaneVehicles", {"car_red": 1.0, "car_white": 1.0, "car_grey": 1.0}, place="lane",
             offset_m=(0.25, 0.4), spacing_m=30.0, density_per_km=3.0, scale=(1.0, 1.0), yaw="along"),
    PropRule("parked_vehicles", "Vehicles", {"car_red": 1.0, "car_white": 1.5, "car_grey": 1.5, "truck": 0.7,
                                             "bus": 0.3}, offset_m=(1.6, 2.5), spacing_m=12.0,
             density_per_km=8.0, scale=(1.0, 1.0), yaw="along"),
    PropRule("guardrails", "Guardrails", {"guardrail": 1.0}, place="chain", offset_m=(0.5, 0.5), spacing_m=4.0,
             density_per_km=30.0, scale=(1.0, 1.0), yaw="along", run_m=(30.0, 90.0)),
    PropRule("utility_poles", "Poles", {"utility_pole": 1.0}, offset_m=(2.5, 2.5), spacing_m=40.0,
             density_per_km=12.0, scale=(1.0, 1.0), yaw="along", wires=True),
    PropRule("signs", "Signs", {"sign_rect": 1.0, "sign_warning": 1.0}, offset_m=(0.8, 1.5), spacing_m=60.0,
             density_per_km=5.0, scale=(1.0, 1.0), yaw="face_traffic"),
    PropRule("km_posts", "KmPosts", {"km_post": 1.0}, offset_m=(0.6, 0.6), spacing_m=100.0, density_per_km=4.0,
             scale=(1.0, 1.0), yaw="along"),
    PropRule("fences", "Fences", {"fence": 1.0}, place="chain", offset_m=(6.0, 6.0), spacing_m=3.0,
             density_per_km=40.0, scale=(1.0, 1.0), yaw="along", run_m=(30.0, 150.0)),
    PropRule("trees", "Trees", {"tree_round": 2.0, "tree_conifer": 1.0}, offset_m=(4.0, 14.0), spacing_m=9.0,
             density_per_km=70.0, scale=(0.8, 1.3)),
    PropRule("shrubs", "Shrubs", {"shrub": 1.0}, offset_m=(1.5, 8.0), spacing_m=5.0, density_per_km=90.0,
             scale=(0.6, 1.4)),
    PropRule("tall_grass", "Grass", {"grass_tuft": 1.0}, offset_m=(0.4, 3.0), spacing_m=1.5, density_per_km=300.0,
             scale=(0.7, 1.4)),
    PropRule("hills", "Hills", {"hill": 1.0}, place="far", offset_m=(180.0, 420.0), spacing_m=90.0,
             density_per_km=8.0, scale=(40.0, 110.0), height_scale=(0.12, 0.3)),
)


@dataclass
class PropGroup:
    """One PointInstancer: its prototypes and instances (world positions, yaw or full
    orientation quaternions (w, x, y, z), per-axis scales, prototype indices)."""

    name: str
    prototypes: list[Prototype]
    positions: np.ndarray
    orientations: np.ndarray
    scales: np.ndarray
    proto_indices: np.ndarray
    rule: str = ""
    place: str = ""     # the rule's place (roadside, chain, lane, far): a view sampler keeps cameras off "lane"

    def __len__(self) -> int:
        return len(self.positions)


@dataclass
class Props:
    groups: list[PropGroup] = field(default_factory=list)
    ground: tuple[np.ndarray, np.ndarray] | None = None    # terrain mesh (vertices, faces), world
    map_objects: dict = field(default_factory=dict)        # the layout's map objects: placed / skipped counts

    @property
    def count(self) -> int:
        return sum(len(g) for g in self.groups)

    def by_rule(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for g in self.groups:
            out[g.rule] = out.get(g.rule, 0) + len(g)
        return out


# ------------------------------------------------------------------------------ rules from TOML
def load_prop_rules(path: str | Path) -> tuple[PropRule, ...]:
    """``[[rule]]`` tables with :class:`PropRule`'s fields (``name``, ``group`` and
    ``prototypes = {tree_round = 2, ...}`` required); ``defaults = true`` at the top keeps the
    built-in rules and adds these (a rule of the same name replaces its default)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise RoadtwinError(f"{path}: props rules file not found") from None
    except OSError as exc:
        raise RoadtwinError(f"{path}: cannot read the props rules file ({exc.strerror or exc})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RoadtwinError(f"{path}: not a TOML props rules file ({exc})") from None
    unknown_top = set(data) - {"rule", "defaults"}
    if unknown_top:
        raise RoadtwinError(f"{path}: unknown key {sorted(unknown_top)[0]!r} (use [[rule]] tables and defaults)")
    if not isinstance(data.get("defaults", False), bool) or not isinstance(data.get("rule", []), list):
        raise RoadtwinError(f"{path}: defaults must be true or false, and rules [[rule]] tables")
    names = {f.name for f in fields(PropRule)}
    rules = []
    for k, table in enumerate(data.get("rule", [])):
        if not isinstance(table, dict):
            raise RoadtwinError(f"{path}: rule {k} is not a table")
        bad = set(table) - names
        if bad:
            raise RoadtwinError(f"{path}: rule {table.get('name', k)!r}: unknown key {sorted(bad)[0]!r} "
                                f"(known: {', '.join(sorted(names))})")
        for req in ("name", "group", "prototypes"):
            if req not in table:
                raise RoadtwinError(f"{path}: rule {table.get('name', k)!r}: missing {req!r}")
        for key in ("name", "group", "place", "yaw"):
            if key in table and not isinstance(table[key], str):
                raise RoadtwinError(f"{path}: rule {table.get('name', k)!r}: {key} must be a string, got {table[key]!r}")
        if not isinstance(table.get("wires", False), bool):
            raise RoadtwinError(f"{path}: rule {table['name']!r}: wires must be true or false")
        try:
            values = {key: (tuple(float(x) for x in v) if isinstance(v, list) else v) for key, v in table.items()}
            values["prototypes"] = {str(p): float(w) for p, w in table["prototypes"].items()}
            for key in ("spacing_m", "density_per_km"):
                if key in values:
                    values[key] = float(values[key])
            rule = PropRule(**values)
            for key in ("offset_m", "scale", "height_scale", "run_m"):
                if len(getattr(rule, key)) != 2:
                    raise ValueError(f"{key} needs two numbers")
        except (TypeError, ValueError, AttributeError) as exc:
            raise RoadtwinError(f"{path}: rule {table.get('name', k)!r}: {exc}") from None
        rules.append(rule.check(str(path)))
    if data.get("defaults", False):
        mine = {r.name for r in rules}
        rules = [r for r in DEFAULT_RULES if r.name not in mine] + rules
    if not rules:
        raise RoadtwinError(f"{path}: no [[rule]] tables")
    if len({r.name for r in rules}) != len(rules):
        raise RoadtwinError(f"{path}: two rules share a name")
    return tuple(rules)


# ------------------------------------------------------------------------------ placement
def paved_surface(segments: list[RoadSegment]):
    polys = [s.polygon() for s in segments if s.kind not in UNPAVED_KINDS]
    if not polys:
        raise RoadtwinError("props: the layout has no paved segments to place props beside")
    # 2 cm simplification first: segment outlines carry many collinear points, and the union
    # of the simplified ones takes half the time (Town01: 0.16 s instead of 0.3 s)
    return shapely.union_all(shapely.simplify(polys, 0.02))


class Ring:
    """A closed outline as numpy: vertices (closing point repeated) and cumulative length;
    oriented so that the outside (away from the polygon) is on its right."""

    def __init__(self, coords) -> None:
        self.xy = np.asarray(coords, dtype=np.float64)[:, :2]
        d = np.linalg.norm(np.diff(self.xy, axis=0), axis=1)
        self.cum = np.concatenate([[0.0], np.cumsum(d)])
        self.length = float(self.cum[-1])

    def at(self, s: np.ndarray) -> np.ndarray:
        s = np.mod(s, self.length) if self.length > 0 else s
        return np.column_stack([np.interp(s, self.cum, self.xy[:, 0]), np.interp(s, self.cum, self.xy[:, 1])])

    def tangent(self, s: np.ndarray, window: float = 0.75) -> np.ndarray:
        t = self.at(s + window) - self.at(s - window)
        return t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)


def _rings(geom) -> list[Ring]:
    out = []
    for poly in getattr(geom, "geoms", [geom]):
        if poly.is_empty or poly.geom_type != "Polygon":
            continue
        p = orient(poly, 1.0)
        out.append(Ring(p.exterior.coords))
        out += [Ring(r.coords) for r in p.interiors]
    return out


def _quat_yaw(yaw: np.ndarray) -> np.ndarray:
    return np.column_stack([np.cos(yaw / 2), np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2)])


def _quat_yaw_pitch(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """q = q_z(yaw) * q_y(pitch): +X tilted by ``pitch`` about Y (positive: nose down), then turned."""
    cy, sy, cp, sp = np.cos(yaw / 2), np.sin(yaw / 2), np.cos(pitch / 2), np.sin(pitch / 2)
    return np.column_stack([cy * cp, -sy * sp, cy * sp, sy * cp])


class _Occupancy:
    """Accepted props as circles in a hash grid: a candidate must clear every one."""

    def __init__(self, cell: float = 8.0):
        self.cell, self.grid, self.rmax = cell, {}, 0.0

    def free(self, x: float, y: float, r: float) -> bool:
        c = self.cell
        reach = int(math.ceil((r + self.rmax) / c))
        i0, j0 = int(math.floor(x / c)), int(math.floor(y / c))
        for i in range(i0 - reach, i0 + reach + 1):
            for j in range(j0 - reach, j0 + reach + 1):
                for (px, py, pr) in self.grid.get((i, j), ()):
                    if (px - x) ** 2 + (py - y) ** 2 < (pr + r) ** 2:
                        return False
        return True

    def add(self, x: float, y: float, r: float) -> None:
        self.rmax = max(self.rmax, r)
        self.grid.setdefault((int(math.floor(x / self.cell)), int(math.floor(y / self.cell))), []).append((x, y, r))


def _rotate(v: np.ndarray, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _choose(rule: PropRule, rng, n: int) -> tuple[list[str], np.ndarray]:
    names = sorted(rule.prototypes)
    w = np.array([rule.prototypes[k] for k in names], float)
    return names, rng.choice(len(names), size=n, p=w / w.sum())


def _stations(length: float, spacing: float, rng) -> np.ndarray:
    n = int(length // spacing)
    if n < 1:
        return np.zeros(0)
    return (np.arange(n) + 0.5 + rng.uniform(-0.3, 0.3, n)) * (length / n)


class PropPlacer:
    def __init__(self, segments: list[RoadSegment], height, seed: int, owner: str):
        self.segments, self.height, self.seed, self.owner = segments, height, seed, owner
        self.paved = paved_surface(segments)
        shapely.prepare(self.paved)
        self.occ = _Occupancy()
        self.outline_km = self.paved.boundary.length / 1000.0
        self.rings = _rings(self.paved)
        self.taken_groups: set[str] = set()      # instancer names already used (the map's)
        self.defect_discs = np.zeros((0, 3))     # (x, y, radius) of the town's defects

    def place(self, rules: tuple[PropRule, ...], strict: bool = True) -> Props:
        out = Props()
        names: set[str] = set(self.taken_groups)
        for k, rule in enumerate(rules):
            rng = np.random.default_rng([self.seed, 7919, k])
            method = {"roadside": self._roadside, "chain": self._chain, "lane": self._lane, "far": self._far}[rule.place]
            groups = method(rule, rng)
            if not sum(len(g) for g in groups) and strict:
                raise RoadtwinError(f"{self.owner}: props rule {rule.name!r} fits nothing: {self._why(rule)}")
            for g in groups:      # one instancer per group: a name two rules share gets a suffix
                base, j = g.name, 1
                while g.name in names:
                    g.name, j = f"{base}_{j}", j + 1
                names.add(g.name)
            out.groups += groups
        return out

    def place_map(self, objects: list[MapObject]) -> tuple[list[PropGroup], dict]:
        """The map's objects as instancers (vehicles apart), each added to the occupancy grid."""
        rows, counts = map_instances(objects, self.segments)
        groups = []
        for group, place, vehicles in (("MapObjects", "map", False), ("MapVehicles", "lane", True)):
            mine = [r for r in rows if r[5] == vehicles]
            if not mine:
                continue
            names = sorted({r[1] for r in mine})
            idx = np.array([names.index(r[1]) for r in mine], np.int64)
            xy = np.array([r[2] for r in mine], np.float64)
            scale = np.array([r[4] for r in mine], np.float64)
            hpr = np.array([r[0].hpr for r in mine], np.float64)
            for i, r in enumerate(mine):
                proto = make_prototype(r[1])
                fp = proto.footprint
                centre = xy[i] + _rotate(0.5 * np.array([fp[0] + fp[2], fp[1] + fp[3]]) * scale[i, :2], hpr[i, 0])
                reach = proto.clearance_m * float(scale[i, :2].max())
                if proto.label in ("guardrail", "fence"):       # a section: half its length, as chains keep
                    reach = max(reach, 0.45 * (fp[2] - fp[0]) * float(scale[i, 0]))
                self.occ.add(float(centre[0]), float(centre[1]), reach)
            rule = PropRule(MAP_RULE, group, {n: 1.0 for n in names}, yaw="along")
            g = self._finish(rule, names, idx, xy, hpr[:, 0], scale, quat_ypr(*hpr.T))
            g.place = place
            groups.append(g)
            self.taken_groups.add(group)
        return groups, counts

    def _why(self, rule: PropRule) -> str:
        longest = max((r.length for r in self.rings), default=0.0)
        if rule.place in ("roadside", "chain") and rule.spacing_m > longest:
            return f"spacing {rule.spacing_m:g} m is longer than every road outline (longest {longest:.1f} m)"
        if rule.place == "lane":
            return "the layout has no driving lane with a centreline, or none had room"
        return (f"no candidate at offset {rule.offset_m[0]:g}..{rule.offset_m[1]:g} m clears the road and the "
                f"props placed before it (density {rule.density_per_km:g}/km, spacing {rule.spacing_m:g} m)")

    def _finish(self, rule, names, idx, xy, yaw, scale, quat=None) -> PropGroup:
        protos = [make_prototype(n) for n in names]
        z = self.height(xy) if len(xy) else np.zeros(0)
        used = sorted(set(idx.tolist()))             # drop prototypes no instance uses
        remap = {u: i for i, u in enumerate(used)}
        return PropGroup(rule.group, [protos[u] for u in used],
                         np.column_stack([xy, z]).astype(np.float64).reshape(-1, 3),
                         (quat if quat is not None else _quat_yaw(yaw)).reshape(-1, 4),
                         np.asarray(scale, np.float64).reshape(-1, 3),
                         np.array([remap[i] for i in idx.tolist()], np.int32), rule.name, rule.place)

    def _roadside(self, rule: PropRule, rng) -> list[PropGroup]:
        mid = 0.5 * (rule.offset_m[0] + rule.offset_m[1])
        half = 0.5 * (rule.offset_m[1] - rule.offset_m[0])
        keep_p = min(1.0, rule.density_per_km * rule.spacing_m / 1000.0)
        names, _ = _choose(rule, np.random.default_rng(0), 0)
        protos = [make_prototype(n) for n in names]
        cand_xy, cand_yaw, cand_ring = [], [], []
        for r_i, ring in enumerate(self.rings):
            s = _stations(ring.length, rule.spacing_m, rng)
            if not len(s):
                continue
            keep = rng.uniform(size=len(s)) < keep_p
            s = s[keep]
            if not len(s):
                continue
            t = ring.tangent(s)
            nrm = np.column_stack([t[:, 1], -t[:, 0]])              # away from the road
            p = ring.at(s) + nrm * (mid + rng.uniform(-half, half, (len(s), 1)))
            along = np.arctan2(t[:, 1], t[:, 0])
            cand_xy.append(p)
            cand_yaw.append(along)
            cand_ring += [r_i] * len(s)
        if not cand_xy:
            return []
        xy, along = np.concatenate(cand_xy), np.concatenate(cand_yaw)
        n = len(xy)
        _, idx = _choose(rule, rng, n)
        sc = rng.uniform(*rule.scale, n)
        hs = rng.uniform(*rule.height_scale, n)
        scale = np.column_stack([sc, sc, sc * hs])
        if rule.yaw == "random":
            yaw = rng.uniform(-np.pi, np.pi, n)
        elif rule.yaw == "face_traffic":
            yaw = along + np.pi    # the plate (normal +X) faces traffic coming along the outline
        else:
            yaw = along
        fps = _footprints(protos, idx, xy, yaw, scale)
        on_road = shapely.intersects(self.paved, fps)
        ok = []
        for i in range(n):
            if on_road[i]:
                continue
            r = protos[idx[i]].clearance_m * sc[i]
            if self.occ.free(xy[i, 0], xy[i, 1], r):
                self.occ.add(xy[i, 0], xy[i, 1], r)
                ok.append(i)
        ok = np.array(ok, np.int64)
        groups = [self._finish(rule, names, idx[ok], xy[ok], yaw[ok], scale[ok])] if len(ok) else []
        if rule.wires and len(ok) > 1:
            groups.append(self._wires(rule, protos, idx[ok], xy[ok], yaw[ok], scale[ok],
                                      np.asarray(cand_ring)[ok], groups[0].positions[:, 2]))
        return groups

    def _wires(self, rule, protos, idx, xy, yaw, scale, ring, z) -> PropGroup:
        """Two wires per span between neighbouring poles of one outline (candidates are in
        outline order), each span two straight pieces through a sagged midpoint."""
        ends_a, ends_b = [], []
        for i in range(len(xy) - 1):
            if ring[i] != ring[i + 1]:
                continue
            d = np.linalg.norm(xy[i + 1] - xy[i])
            if not (3.0 < d < 2.2 * rule.spacing_m):
                continue
            for side in range(2):
                pa = self._attach(protos[idx[i]], side, xy[i], z[i], yaw[i], scale[i])
                pb = self._attach(protos[idx[i + 1]], side, xy[i + 1], z[i + 1], yaw[i + 1], scale[i + 1])
                mid = 0.5 * (pa + pb) - np.array([0.0, 0.0, 0.012 * d])
                ends_a += [pa, mid]
                ends_b += [mid, pb]
        a, b = np.array(ends_a).reshape(-1, 3), np.array(ends_b).reshape(-1, 3)
        v = b - a
        length = np.linalg.norm(v, axis=1)
        yaw_w = np.arctan2(v[:, 1], v[:, 0])
        pitch = -np.arctan2(v[:, 2], np.linalg.norm(v[:, :2], axis=1))
        proto = make_prototype("wire")
        return PropGroup("Wires", [proto], a, _quat_yaw_pitch(yaw_w, pitch),
                         np.column_stack([length, np.ones_like(length), np.ones_like(length)]),
                         np.zeros(len(a), np.int32), rule.name, rule.place)

    @staticmethod
    def _attach(proto, side, xy, z, yaw, scale):
        p = proto.attach[side] * scale
        c, s = math.cos(yaw), math.sin(yaw)
        return np.array([xy[0] + c * p[0] - s * p[1], xy[1] + s * p[0] + c * p[1], z + p[2]])

    def _chain(self, rule: PropRule, rng) -> list[PropGroup]:
        """Runs of sections (``spacing_m`` long) end to end along the outline at the rule's
        offset, at seeded stations, covering on average ``density_per_km * spacing_m / 1000`` of
        it; a section whose footprint touches the road or another prop is left out."""
        names, _ = _choose(rule, np.random.default_rng(0), 0)
        protos = [make_prototype(n) for n in names]
        section = rule.spacing_m
        xy_all, yaw_all, idx_all, len_all = [], [], [], []
        cover = min(1.0, rule.density_per_km * section / 1000.0)
        for ring in self.rings:
            if ring.length < section:
                continue
            # runs at seeded stations: on average ``cover`` of the outline, as runs of run_m
            mean_run = 0.5 * (rule.run_m[0] + rule.run_m[1])
            n_runs = int(cover * ring.length / mean_run + rng.uniform())
            for s in np.sort(rng.uniform(0, ring.length, n_runs)):
                run = rng.uniform(*rule.run_m)
                k = max(1, int(min(run, ring.length - s) // section))
                st = s + section * np.arange(k + 1)
                t = ring.tangent(st, 2.0)
                pts = ring.at(st) + np.column_stack([t[:, 1], -t[:, 0]]) * rule.offset_m[0]
                seg = np.diff(pts, axis=0)
                ln = np.linalg.norm(seg, axis=1)
                good = ln > 0.5 * section
                xy_all.append(pts[:-1][good])
                yaw_all.append(np.arctan2(seg[good, 1], seg[good, 0]))
                len_all.append(ln[good])
        if not xy_all:
            return []
        xy, yaw, ln = np.concatenate(xy_all), np.concatenate(yaw_all), np.concatenate(len_all)
        _, idx = _choose(rule, rng, len(xy))
        sec_len = np.array([protos[i].footprint[2] for i in idx])   # sections run from x = 0 to their length
        scale = np.column_stack([ln / sec_len, np.ones(len(xy)), np.ones(len(xy))])
        fps = _footprints(protos, idx, xy, yaw, scale)
        on_road = shapely.intersects(self.paved, fps)
        ok = []
        for i in range(len(xy)):
            cx, cy = xy[i] + 0.5 * ln[i] * np.array([math.cos(yaw[i]), math.sin(yaw[i])])
            if not on_road[i] and self.occ.free(cx, cy, 0.5 * ln[i] * 0.9):
                ok.append(i)
        for i in ok:   # added after the test: neighbouring sections of a run touch each other
            cx, cy = xy[i] + 0.5 * ln[i] * np.array([math.cos(yaw[i]), math.sin(yaw[i])])
            self.occ.add(cx, cy, 0.5 * ln[i] * 0.9)
        ok = np.array(ok, np.int64)
        return [self._finish(rule, names, idx[ok], xy[ok], yaw[ok], scale[ok])] if len(ok) else []

    def _lane(self, rule: PropRule, rng) -> list[PropGroup]:
        """Vehicles stopped at the right edge of driving lanes (``offset_m``: gap to the edge). A
        spot taken (a defect, an earlier prop) moves the vehicle along its lane, to the first
        clear one of :data:`LANE_SHIFTS_M` (a car does not stop on a pothole)."""
        names, _ = _choose(rule, np.random.default_rng(0), 0)
        protos = [make_prototype(n) for n in names]
        keep_p = min(1.0, rule.density_per_km * rule.spacing_m / 1000.0)
        xy_all, yaw_all, idx_all = [], [], []
        for seg in self.segments:
            if seg.kind != "driving" or seg.centerline is None or len(seg.centerline) < 2:
                continue
            line = Ring(seg.centerline)
            if line.length < 1.0:
                continue
            width = seg.polygon().area / line.length
            n = int(line.length / rule.spacing_m + rng.uniform())     # short segments: by chance
            s = (np.arange(n) + rng.uniform(0.2, 0.8, n)) * (line.length / max(n, 1))
            keep = rng.uniform(size=len(s)) < keep_p
            _, idx = _choose(rule, rng, len(s))
            gap = rng.uniform(*rule.offset_m, len(s))
            s, idx, gap = s[keep], idx[keep], gap[keep]
            if not len(s):
                continue
            spots = np.clip(s[:, None] + LANE_SHIFTS_M[None, :], 0.0, line.length).ravel()   # (N * K)
            p = line.at(spots)
            t = line.tangent(spots, 0.5)
            right = np.column_stack([t[:, 1], -t[:, 0]])
            half_w = np.repeat([0.5 * (protos[i].footprint[3] - protos[i].footprint[1]) for i in idx],
                               len(LANE_SHIFTS_M))
            off = np.maximum(np.repeat(width / 2 - gap, len(LANE_SHIFTS_M)) - half_w, 0.0)
            xy_all.append((p + right * off[:, None]).reshape(len(s), -1, 2))
            yaw_all.append(np.arctan2(t[:, 1], t[:, 0]).reshape(len(s), -1))
            idx_all.append(idx)
        if not xy_all:
            return []
        xy, yaw, idx = np.concatenate(xy_all), np.concatenate(yaw_all), np.concatenate(idx_all)
        ok, at = [], []
        for i in range(len(xy)):
            r = protos[idx[i]].clearance_m
            for j in range(xy.shape[1]):
                if self.occ.free(xy[i, j, 0], xy[i, j, 1], r):
                    self.occ.add(xy[i, j, 0], xy[i, j, 1], r)
                    ok.append(i)
                    at.append(j)
                    break
        ok, at = np.array(ok, np.int64), np.array(at, np.int64)
        return ([self._finish(rule, names, idx[ok], xy[ok, at], yaw[ok, at], np.ones((len(ok), 3)))]
                if len(ok) else [])

    def _far(self, rule: PropRule, rng) -> list[PropGroup]:
        names, _ = _choose(rule, np.random.default_rng(0), 0)
        mid = 0.5 * (rule.offset_m[0] + rule.offset_m[1])
        half = 0.5 * (rule.offset_m[1] - rule.offset_m[0])
        hull = self.paved.convex_hull.buffer(mid, quad_segs=4)
        ring = _rings(hull)[0]
        s = _stations(ring.length, rule.spacing_m, rng)
        keep = rng.uniform(size=len(s)) < min(1.0, rule.density_per_km * rule.spacing_m / 1000.0)
        s = s[keep]
        if not len(s):
            return []
        t = ring.tangent(s)
        p = ring.at(s) + np.column_stack([t[:, 1], -t[:, 0]]) * rng.uniform(-half, half, (len(s), 1))
        _, idx = _choose(rule, rng, len(s))
        r = rng.uniform(*rule.scale, len(s))
        scale = np.column_stack([r, r * rng.uniform(0.6, 1.0, len(s)), r * rng.uniform(*rule.height_scale, len(s))])
        yaw = rng.uniform(-np.pi, np.pi, len(s))
        return [self._finish(rule, names, idx, p, yaw, scale)]

    def ground(self):
        """Terrain under the town, nowhere inside the paved surface (0.5 m in from its edge) nor
        under a defect's disc (:func:`roadtwin_core.town.terrain.terrain_mesh`)."""
        return terrain_mesh(self.paved, self.height, self.defect_discs)


def place_props(segments: list[RoadSegment], rules: tuple[PropRule, ...], height, seed: int, owner: str,
                ground: bool = True, strict: bool | None = None, taken: np.ndarray | None = None,
                map_objects: list[MapObject] = ()) -> Props:
    """The props of a town. ``height(xy) -> z``: the ground under points (the compose surface
    model, so props stand on the same elevation as the road). ``strict``: a rule that places
    nothing is an error (default: for rules other than the built-in ones, which fit what they can).
    ``taken``: (N,3) discs (x, y, radius) already in use, the town's defects: no prop's clearance
    overlaps one (a car stopped in the lane does not hide a pothole). ``map_objects``: the layout's
    own objects, placed first as the instancers ``MapObjects`` / ``MapVehicles``
    (:mod:`roadtwin_core.town.map_props`); the rules fill around them."""
    rules = tuple(r.check(owner) for r in rules)
    if strict is None:
        strict = rules != DEFAULT_RULES
    placer = PropPlacer(segments, height, seed, owner)
    placer.defect_discs = np.asarray(taken if taken is not None else np.zeros((0, 3)), np.float64).reshape(-1, 3)
    for x, y, r in placer.defect_discs:
        placer.occ.add(float(x), float(y), float(r))
    mapped = placer.place_map(list(map_objects)) if map_objects else None
    props = placer.place(rules, strict)
    if mapped is not None:
        props.groups = mapped[0] + props.groups
        props.map_objects = mapped[1]
    if ground:
        props.ground = placer.ground()
    return props


__all__ = ["DEFAULT_RULES", "PropGroup", "PropRule", "Props", "load_prop_rules", "paved_surface", "place_props"]
