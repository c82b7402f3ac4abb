"""The CDT merger (Zhang et al.'s digital road twin generator, steps 2-5 of
docs/architecture.md#the-merger).

Per segment: re-mesh the planar road evenly; project each defect footprint vertically onto it
and mark covered triangles (batched Möller–Trumbore rays plus a vertex-in-footprint test, both
against the footprint grown by a ring margin); remove them; fill the gap between the hole's
rim and each defect's boundary loop with a constrained Delaunay triangulation (Triangle, -YY:
no Steiner points on the rim or the loop, so road and defect share exactly those vertices);
restore elevation from the surface model. A defect that straddles the segment border is
clipped to the segment first, so each neighbour gets its own part with identical border points.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
import triangle

from roadtwin_core import (ComposeRules, MergedSegment, Placement, RoadSegment, RoadtwinError,
                           SurfaceModel, field)
from roadtwin_core.geometry import boundary_edges, triangle_min_angles, vertical_ray_hits_pairs
from roadtwin_core.remesh import even_segment_mesh

from .clip import DefectPiece, clip_defect

STEINER_PER_VERTEX = 20      # Triangle's -S bound on the points a ring's refinement may add, per input vertex


def refine(tri_in: dict, switches: str) -> dict | None:
    """``triangle.triangulate`` with the Steiner points bounded; None where the bound is reached.
    Why: a footprint loop whose vertex lies on its own next segment (a zero input angle, as
    pixel-traced photo cracks clipped to a segment can have) sends Ruppert's refinement on
    forever: a highway compose grew to 60 GB. Normal rings add a few points per vertex; one that
    reaches the bound is left to the caller's coarser triangulation (what Triangle made of it by
    then has slivers of zero area at the degenerate vertex)."""
    bound = STEINER_PER_VERTEX * len(tri_in["vertices"]) + 1000
    out = triangle.triangulate(tri_in, f"{switches}S{bound}")
    return None if len(out["vertices"]) - len(tri_in["vertices"]) >= bound else out


@dataclass
class CDTParams:
    ring_margin_m: float = field(0.0, lo=0.0, doc="road cut around each defect; 0 means 1.2 x the road edge")
    min_angle_deg: float = field(20.5, lo=0.0, hi=30.0, doc="quality bound of the re-triangulated ring")


class _SeamBroken(Exception):
    """A defect loop crossed a kept road edge; retried with a wider cut."""


class _LowQuality(Exception):
    """Ring triangles below the angle bound sit on these rim edges; retried with them cut."""

    def __init__(self, rim_edges: np.ndarray) -> None:
        self.rim_edges = rim_edges


def _faces_on_edges(faces: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Faces that use any of the given undirected edges."""
    n = int(max(faces.max(), edges.max())) + 1
    e = np.sort(edges, axis=1)
    keys = e[:, 0] * n + e[:, 1]
    fe = np.sort(np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1), axis=2)
    return np.isin(fe[..., 0] * n + fe[..., 1], keys).any(axis=1)


class CDTMerger:
    name = "cdt"
    description = "Möller–Trumbore cut + constrained Delaunay ring + k-d tree elevation (Zhang et al.)"
    Params = CDTParams

    def __init__(self, params: CDTParams | None = None) -> None:
        self.params = params or CDTParams()

    def merge(self, segment: RoadSegment, placements: list[Placement], surface: SurfaceModel,
              rules: ComposeRules) -> MergedSegment:
        h = rules.road_edge_m
        v2, faces, border = even_segment_mesh(segment, h)
        poly = segment.polygon()
        shapely.prepare(poly)   # one contains() per defect below; same answers, faster
        clipped = [clip_defect(p, poly, v2, border, f"defect {p.instance_id!r} on segment {segment.id!r}")
                   for p in placements]
        owners = [i for i, pc in enumerate(clipped) if pc is not None]
        pieces = [clipped[i] for i in owners]
        if not pieces:  # no defect (or one that only touches the border): the road as re-meshed
            return MergedSegment(segment.id, np.column_stack([v2, surface.height(v2)]), faces,
                                 np.full(len(faces), -1, dtype=np.int64))
        margin = self.params.ring_margin_m or 1.2 * h
        removed = covered_triangles(v2, faces, [pc.region for pc in pieces], margin, h)
        strict = True
        for attempt in range(10):
            # Growing the cut for quality is bounded: the last attempts keep the best effort.
            strict = strict and attempt < 8
            try:
                return self._assemble(segment, v2, faces, removed, pieces, owners, surface, strict,
                                      poly.boundary)
            except _SeamBroken:
                margin *= 2.0
                removed = covered_triangles(v2, faces, [pc.region for pc in pieces], margin, h)
            except _LowQuality as low:
                # A rim edge too long for its neighbourhood: cut the road triangle behind it too.
                grow = _faces_on_edges(faces, low.rim_edges) & ~removed
                if not grow.any():
                    # Only the segment's own border is left behind the skinny triangles; it may not
                    # move, so keep the best triangulation Triangle found there.
                    strict = False
                removed |= grow
        raise RoadtwinError(f"segment {segment.id!r}: could not merge its defects (footprints too close to each other?)")

    def _assemble(self, segment, v2, faces, removed, pieces: list[DefectPiece], owners: list[int],
                  surface, strict: bool = True, border_line=None) -> MergedSegment:
        if border_line is None:
            border_line = segment.polygon().boundary
        # Global vertex table: road vertices first, then defect piece vertices (reusing any road
        # vertex a clipped piece shares bit-for-bit, e.g. a border vertex inside the footprint).
        piece_xyz = np.concatenate([pc.vertices for pc in pieces])
        keys = np.concatenate([v2, piece_xyz[:, :2]])
        canon = _first_equal_row(keys)
        rows = np.arange(len(keys))
        is_new = (canon == rows) & (rows >= len(v2))
        new_id = np.cumsum(is_new) - 1 + len(v2)
        gid = np.where(canon < len(v2), canon, new_id[canon])
        all_xy = np.concatenate([v2, keys[is_new]])
        all_rel = np.zeros(len(all_xy))
        all_rel[gid[len(v2):]] = piece_xyz[:, 2]
        offsets = np.cumsum([len(v2)] + [len(pc.vertices) for pc in pieces])
        piece_ids = [gid[a:b] for a, b in zip(offsets[:-1], offsets[1:])]

        ring_faces, steiner = ring_cdt(all_xy, faces[removed], pieces, piece_ids, self.params.min_angle_deg,
                                       segment.id, border_line)
        chains: dict = {}
        angles = triangle_min_angles(np.concatenate([all_xy, steiner]), ring_faces)
        bad = angles < self.params.min_angle_deg - 0.5
        if strict and bad.any():
            rim = {tuple(sorted(e)) for e in boundary_edges(faces[removed]).tolist()}
            edges = np.sort(np.concatenate([ring_faces[bad][:, [0, 1]], ring_faces[bad][:, [1, 2]],
                                            ring_faces[bad][:, [2, 0]]]), axis=1)
            on_rim = np.array([tuple(e) in rim for e in edges.tolist()])
            if on_rim.any():
                raise _LowQuality(edges[on_rim])
            # -YY rejected the Steiner points that would fix these triangles (they encroach a rim
            # or loop segment). Let Triangle split segments: a split rim edge means the cut is
            # too tight there (grow it behind that edge); a split loop edge is taken, and the
            # defect face on it is split at the same points (on the border at pseudo-height, or
            # linearly interpolated: the defect surface is unchanged).
            tris, new_xy, loop_chains, rim_split, blocked = ring_cdt_split(
                all_xy, faces[removed], pieces, piece_ids, self.params.min_angle_deg, segment.id,
                border_line)
            if len(rim_split):
                raise _LowQuality(rim_split)
            if not blocked:
                ring_faces, steiner, chains = tris, new_xy, loop_chains
        if len(steiner):
            new_rel = np.zeros(len(steiner))
            for (a, b), chain in chains.items():
                for i in chain:
                    p = steiner[i - len(all_xy)]
                    d = all_xy[b] - all_xy[a]
                    t = float(np.dot(p - all_xy[a], d) / np.dot(d, d))
                    new_rel[i - len(all_xy)] = (1 - t) * all_rel[a] + t * all_rel[b]
            all_xy = np.concatenate([all_xy, steiner])
            all_rel = np.concatenate([all_rel, new_rel])

        kept = faces[~removed]
        piece_faces = [_split_faces(ids[pc.faces], chains, all_xy) for pc, ids in zip(pieces, piece_ids)]
        parts = [kept, ring_faces] + piece_faces
        owners = [np.full(len(kept), -1), np.full(len(ring_faces), -1)] + [
            np.full(len(pf), owners[i]) for i, pf in enumerate(piece_faces)]
        all_faces = np.concatenate(parts).astype(np.int64)
        owner = np.concatenate(owners).astype(np.int64)
        ring_index = np.arange(len(kept), len(kept) + len(ring_faces), dtype=np.int64)

        used, inverse = np.unique(all_faces, return_inverse=True)
        all_faces = inverse.reshape(-1, 3).astype(np.int64)
        xy_used = all_xy[used]
        z = surface.height(xy_used) + all_rel[used]
        return MergedSegment(segment.id, np.column_stack([xy_used, z]), all_faces, owner, ring_index)


def _first_equal_row(xy: np.ndarray) -> np.ndarray:
    """For each row, the smallest index of a row with the same (x, y) values: what
    ``first[inverse]`` of ``np.unique(xy, axis=0, return_index=True, return_inverse=True)`` is,
    from one stable lexsort (``np.unique`` on rows sorts a structured view, several times slower)."""
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    s = xy[order]
    start = np.r_[True, (s[1:, 0] != s[:-1, 0]) | (s[1:, 1] != s[:-1, 1])]
    group = np.cumsum(start) - 1
    canon = np.empty(len(xy), dtype=np.int64)
    canon[order] = order[start][group]
    return canon


def covered_triangles(v2: np.ndarray, faces: np.ndarray, regions: list, margin: float, h: float) -> np.ndarray:
    """Triangles within ``margin`` of any defect region: vertices inside the grown region, or hit
    by vertical rays cast from the grown region's rim.

    All defects of the segment at once (shapely's array functions, one batched Möller–Trumbore
    call over the (ray, triangle) pairs whose bounding boxes meet): a Python loop per defect
    cost more than the tests themselves on a segment with a hundred defects."""
    tri = np.zeros((len(faces), 3, 3))
    tri[:, :, :2] = v2[faces]
    tmin = tri[:, :, :2].min(axis=1)
    tmax = tri[:, :, :2].max(axis=1)
    grown = shapely.buffer(np.asarray(regions, dtype=object), margin, quad_segs=4)
    box = shapely.bounds(grown)                                          # (R, 4)
    # Vertices strictly inside a grown region (candidates: inside its bounding box).
    vin = ((v2[None, :, 0] >= box[:, None, 0]) & (v2[None, :, 0] <= box[:, None, 2])
           & (v2[None, :, 1] >= box[:, None, 1]) & (v2[None, :, 1] <= box[:, None, 3]))
    r_idx, v_idx = np.nonzero(vin)
    inside = np.zeros(len(v2), dtype=bool)
    inside[v_idx[shapely.contains_xy(grown[r_idx], v2[v_idx, 0], v2[v_idx, 1])]] = True
    removed = inside[faces].any(axis=1)
    # Rays from the grown rims. A defect clipped to a non-convex segment can fall apart into
    # several polygons; rays from every part's rim suffice: a triangle that meets the footprint
    # but has no vertex in the grown region is larger than the margin and so is crossed by it.
    step = max(min(margin, h) / 2.0, 1e-3)
    parts, part_region = shapely.get_parts(grown, return_index=True)
    rims = shapely.segmentize(shapely.get_exterior_ring(parts), step)
    origins, origin_part = shapely.get_coordinates(rims, return_index=True)
    origin_region = part_region[origin_part]                             # sorted by region
    tin = ((tmax[None, :, 0] >= box[:, None, 0]) & (tmin[None, :, 0] <= box[:, None, 2])
           & (tmax[None, :, 1] >= box[:, None, 1]) & (tmin[None, :, 1] <= box[:, None, 3]))
    cand = np.flatnonzero(tin.any(axis=0))                               # triangles near any region
    if not len(cand) or not len(origins):
        return removed
    # (ray, triangle) pairs: a ray of region r against the triangles near r whose XY box (grown
    # as vertical_ray_hits_pairs grows it) holds the ray; an STRtree finds them instead of
    # listing every (ray, near triangle) pair. The same pairs reach the same arithmetic.
    lo, hi = tmin[cand] - 1e-6, tmax[cand] + 1e-6
    tree = shapely.STRtree(shapely.box(lo[:, 0], lo[:, 1], hi[:, 0], hi[:, 1]))
    pair_origin, pair_cand = tree.query(shapely.points(origins))
    pair_tri = cand[pair_cand]
    mine = tin[origin_region[pair_origin], pair_tri]
    pair_origin, pair_tri = pair_origin[mine], pair_tri[mine]
    hits = vertical_ray_hits_pairs(origins, tri, pair_origin, pair_tri, top=1.0)
    removed[pair_tri[hits]] = True
    return removed


def _ring_input(all_xy, removed_faces, pieces, piece_ids, border_line=None):
    """Triangle's input for the ring: rim and loop segments, hole seeds. Returns the input,
    the global ids of its vertices, and the input segments (global ids, sorted pairs)."""
    rim = boundary_edges(removed_faces)
    loop_edges = [np.column_stack([ids[l], ids[np.roll(l, -1)]]) for pc, ids in zip(pieces, piece_ids)
                  for l in pc.loops]
    loop_edges = np.concatenate(loop_edges) if loop_edges else np.zeros((0, 2), dtype=np.int64)
    # Only loop vertices of clipped pieces can lie on a rim edge (on the segment's border).
    cand = np.unique(loop_edges)
    if len(cand) and border_line is not None:
        cand = cand[shapely.distance(border_line, shapely.points(all_xy[cand])) <= 1e-9]
    island_seeds = _island_seeds(all_xy, removed_faces, rim)
    rim = _split_at_points(rim, all_xy, cand)
    edges = np.sort(np.concatenate([rim, loop_edges]), axis=1)
    # Unique sorted pairs through 1D keys (same order as np.unique(axis=0), several times faster).
    n = int(edges.max()) + 1
    key = np.unique(edges[:, 0] * n + edges[:, 1])
    key = np.column_stack([key // n, key % n])
    key = key[key[:, 0] != key[:, 1]]
    ids = np.unique(key)
    local = np.full(int(ids.max()) + 1, -1, dtype=np.int64)
    local[ids] = np.arange(len(ids))
    holes = [pc.seed for pc in pieces] + [s for pc in pieces for s in pc.extra_seeds]
    holes += island_seeds
    tri_in = {"vertices": all_xy[ids], "segments": local[key]}
    if holes:
        tri_in["holes"] = np.array(holes)
    return tri_in, ids, key, loop_edges


def ring_cdt(all_xy: np.ndarray, removed_faces: np.ndarray, pieces: list[DefectPiece],
             piece_ids: list[np.ndarray], min_angle: float, segment_id: str,
             border_line=None) -> tuple[np.ndarray, np.ndarray]:
    """Constrained Delaunay fill of (cut region) minus (defect pieces). Returns faces (global ids)
    and the Steiner points Triangle added inside the ring (never on its rim)."""
    tri_in, ids, _, _ = _ring_input(all_xy, removed_faces, pieces, piece_ids, border_line)
    out = refine(tri_in, f"pq{min_angle}YY") or triangle.triangulate(tri_in, "pYY")
    out_v = out["vertices"]
    out_segs = np.sort(out.get("segments", np.zeros((0, 2), dtype=np.int64)), axis=1)
    # Triangle only adds a vertex on a segment where two segments cross: a loop crossing the rim.
    if (out_segs >= len(ids)).any() or not np.array_equal(out_v[: len(ids)], all_xy[ids]):
        raise _SeamBroken(segment_id)
    tris = out["triangles"].astype(np.int64)
    n_in = len(ids)
    glob = np.concatenate([ids, len(all_xy) + np.arange(len(out_v) - n_in)])
    return glob[tris], out_v[n_in:]


def ring_cdt_split(all_xy: np.ndarray, removed_faces: np.ndarray, pieces: list[DefectPiece],
                   piece_ids: list[np.ndarray], min_angle: float, segment_id: str, border_line):
    """The ring as :func:`ring_cdt`, but Triangle may split rim and loop segments.

    With -YY Triangle rejects every Steiner point that would encroach a segment, so a triangle
    whose fix lies in a segment's diametral lens stays below the angle bound (Ruppert's
    guarantee needs segment splitting). Here Triangle splits what it needs. Returns
    (faces in global ids, new points (global ids from len(all_xy) on), {(a, b): new ids
    along the loop edge a -> b (a < b)}, split rim edges (global ids), blocked) where
    ``blocked`` says an edge on the segment's own border was split (it may not be), or the
    refinement reached its bound (:func:`refine`): the caller keeps its ring unsplit.
    """
    tri_in, ids, key, loop_edges = _ring_input(all_xy, removed_faces, pieces, piece_ids, border_line)
    out = refine(tri_in, f"pq{min_angle}")
    if out is None:                  # no end to splitting here: keep the ring without split segments
        return None, None, {}, np.zeros((0, 2), np.int64), True
    out_v = out["vertices"]
    n_in = len(ids)
    if not np.array_equal(out_v[:n_in], all_xy[ids]):
        raise _SeamBroken(segment_id)
    glob = np.concatenate([ids, len(all_xy) + np.arange(len(out_v) - n_in)])
    tris = glob[out["triangles"].astype(np.int64)]
    on_seg = np.unique(out.get("segments", np.zeros((0, 2), dtype=np.int64)))
    on_seg = on_seg[on_seg >= n_in]
    loops = {tuple(e) for e in np.sort(loop_edges, axis=1).tolist()}
    chains: dict[tuple[int, int], list[tuple[float, int]]] = {}
    if len(on_seg):
        a, b = all_xy[key[:, 0]], all_xy[key[:, 1]]
        d = b - a
        for p_local in on_seg:
            p = out_v[p_local]
            t = np.clip(((p - a) * d).sum(1) / (d * d).sum(1), 0.0, 1.0)
            k = int(np.argmin(np.linalg.norm(a + t[:, None] * d - p, axis=1)))
            chains.setdefault((int(key[k, 0]), int(key[k, 1])), []).append((float(t[k]), int(glob[p_local])))
    split_edges = np.array(sorted(chains), dtype=np.int64).reshape(-1, 2)
    mid = 0.5 * (all_xy[split_edges[:, 0]] + all_xy[split_edges[:, 1]])
    blocked = bool(len(mid)) and bool((shapely.distance(border_line, shapely.points(mid)) <= 1e-9).any())
    rim_split = np.array([e for e in split_edges.tolist() if tuple(e) not in loops], dtype=np.int64).reshape(-1, 2)
    loop_chains = {e: [i for _, i in sorted(c)] for e, c in chains.items() if e in loops}
    return tris, out_v[n_in:], loop_chains, rim_split, blocked


def _split_faces(faces: np.ndarray, chains: dict, xy: np.ndarray) -> np.ndarray:
    """Re-triangulate (without new points) the faces with an edge split at the chain points."""
    if not chains:
        return faces
    out = []
    for f in faces.tolist():
        ring = []
        for k in range(3):
            a, b = f[k], f[(k + 1) % 3]
            ring.append(a)
            if (min(a, b), max(a, b)) in chains:
                c = chains[(min(a, b), max(a, b))]
                ring.extend(c if a < b else c[::-1])
        if len(ring) == 3:
            out.append(f)
            continue
        n = len(ring)
        t = triangle.triangulate({"vertices": xy[ring], "segments": np.column_stack(
            [np.arange(n), (np.arange(n) + 1) % n])}, "pQ")
        if len(t["vertices"]) != n:
            raise RoadtwinError("splitting a defect face along its border added points")
        out.extend(np.asarray(ring)[t["triangles"]].tolist())
    return np.asarray(out, dtype=np.int64).reshape(-1, 3)


def _split_at_points(edges: np.ndarray, xy: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Split rim edges at loop vertices lying on them (clipped defects meet the segment border).
    The edges come back in no particular order (unsplit ones first)."""
    if len(candidates) == 0 or len(edges) == 0:
        return edges
    a, b = xy[edges[:, 0]], xy[edges[:, 1]]
    p = xy[candidates]
    d = b - a
    L2 = (d * d).sum(1)
    t = ((p[:, None, :] - a[None]) * d[None]).sum(-1) / L2[None]
    foot = a[None] + t[..., None] * d[None]
    dist = np.linalg.norm(p[:, None, :] - foot, axis=-1)
    scale = np.sqrt(L2)[None]
    on = (dist <= 1e-9 * np.maximum(scale, 1.0)) & (t > 1e-12) & (t < 1 - 1e-12)
    on &= (candidates[:, None] != edges[None, :, 0]) & (candidates[:, None] != edges[None, :, 1])
    split = on.any(axis=0)
    if not split.any():
        return edges
    # The caller keys the rim by sorted pairs, so edge order is free: unsplit edges first.
    out = [edges[~split]]
    for e in np.flatnonzero(split):
        hit = np.flatnonzero(on[:, e])
        order = hit[np.argsort(t[hit, e])]
        chain = np.concatenate([[edges[e, 0]], candidates[order], [edges[e, 1]]])
        out.append(np.column_stack([chain[:-1], chain[1:]]))
    return np.concatenate(out)


def _island_seeds(xy: np.ndarray, removed_faces: np.ndarray, rim: np.ndarray | None = None
                  ) -> list[tuple[float, float]]:
    """A point inside every kept-road island enclosed by the cut, so Triangle leaves it alone.

    The islands are the bounded faces of the rim's arrangement that the cut does not cover.
    (Holes of the cut's union are not enough: an island enclosed by two cut regions that touch
    only at vertices is a hole of neither, and the ring would be laid over it.)
    """
    if rim is None:
        rim = boundary_edges(removed_faces)
    if not _may_enclose(removed_faces, rim):
        return []
    faces = shapely.get_parts(shapely.polygonize(shapely.linestrings(xy[rim])))
    if not len(faces):
        return []
    # A point is covered by the cut iff one of its (closed) triangles covers it: no union needed.
    rps = shapely.point_on_surface(faces)
    covered_rp, _ = shapely.STRtree(shapely.polygons(xy[removed_faces])).query(rps, predicate="covered_by")
    free = np.setdiff1d(np.arange(len(rps)), covered_rp)
    return [tuple(c) for c in shapely.get_coordinates(rps[free]).tolist()]


def _may_enclose(faces: np.ndarray, rim: np.ndarray) -> bool:
    """False when every connected cut region is a disk (one rim loop each, no pinched vertex):
    then nothing is enclosed and the costly island search can be skipped.

    Without a pinched rim vertex every region is a planar surface and its rim loops are disjoint
    cycles, so Euler's V - E + F = sum over regions of (2 - loops) = 2 C - L, and all regions are
    disks (C == L) exactly when V - E + F == L. Counting beats two graph labellings (scipy's
    overhead dominated on a few hundred triangles)."""
    if not len(rim):
        return False
    if np.bincount(rim[:, 0]).max() > 1:
        return True  # a pinched rim vertex: loops are ambiguous, search properly
    n_vertices = len(np.unique(faces))
    n_edges = (3 * len(faces) + len(rim)) // 2     # inner edges have two faces, rim edges one
    euler = n_vertices - n_edges + len(faces)
    return euler != _cycle_count(rim)


def _cycle_count(edges: np.ndarray) -> int:
    """Number of cycles of directed edges where every vertex has one successor (pointer
    jumping: each vertex learns the smallest id on its cycle in log2(len) rounds)."""
    nxt = np.arange(int(edges.max()) + 1)
    nxt[edges[:, 0]] = edges[:, 1]
    label = np.arange(len(nxt))
    for _ in range(max(int(len(edges)).bit_length(), 1)):
        label = np.minimum(label, label[nxt])
        nxt = nxt[nxt]
    v = edges[:, 0]
    return int((label[v] == v).sum())


__all__ = ["CDTMerger", "CDTParams", "covered_triangles", "ring_cdt", "ring_cdt_split"]
