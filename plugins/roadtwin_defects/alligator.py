"""Alligator (fatigue) cracking: a wheel-path area of interconnected cracks in small polygonal cells.

Why a type of its own: what road surveys label "crack" is mostly this (road_defects_br's train
labels: speckled networks metres long along the wheel paths, docs/realism/README.md), while the
``crack`` type grows one branching tree. ASTM D6433 ("alligator cracking"): a series of
interconnecting cracks forming many-sided, sharp-angled pieces, usually under 0.3 m on the
longest side, in the wheel paths.

Shape: the cells are the Voronoi regions of a jittered triangular lattice (near-hexagons, corner
angles near 120 deg, so the outline has no sharp notch), clipped to an ellipse along travel (+x).
A DefectModel is one polygon without holes, and a closed cell would enclose a road island; so
the cell edges are kept as a tree: a breadth-first spanning tree from the middle, and every other
edge as a stub hanging from one end that stops short of the other (a gap of 1.4 clearances, 2-5 cm:
a hairline break in the network, under a pixel at survey range). The grooves are the crack
type's V-section (``depth_m`` on the centreline, 0 at half ``groove_m``) with the crack finish.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial import Voronoi
from shapely.geometry import LineString, MultiLineString, Point

from roadtwin_core import DefectModel, RoadtwinError, check_params, field

from .crack import groove_network


class Alligator:
    name = "alligator"
    material = "crack"          # the catalog material it wears (contracts.DefectType): the crack finish
    along_travel = True         # placed with the lane's direction (contracts.DefectType)
    description = "Alligator (fatigue) cracking: a wheel-path area of small polygonal crack cells along travel (+x)."

    @dataclass
    class Params:
        length_m: float = field(2.0, lo=0.2, hi=10.0, doc="extent of the cracked area along travel (+x)")
        width_m: float = field(0.7, lo=0.1, hi=3.0, doc="extent across travel (+y)")
        cell_m: float = field(0.2, lo=0.05, hi=1.0, doc="spacing of the cells' centres (a cell's width)")
        jitter: float = field(0.15, lo=0.0, hi=0.3, doc="random shift of the cell centres, a share of cell_m")
        groove_m: float = field(0.012, lo=0.002, hi=0.05, doc="groove width at the road surface")
        depth_m: float = field(0.006, lo=0.0005, hi=0.05, doc="groove depth on the centreline")

    def sample_params(self, rng: np.random.Generator) -> "Alligator.Params":
        width = rng.uniform(0.4, 1.1)
        cell = rng.uniform(0.12, min(0.3, width / 2))
        return self.Params(length_m=rng.uniform(max(1.0, 1.5 * width), 5.0), width_m=width, cell_m=cell,
                           jitter=rng.uniform(0.1, 0.3), groove_m=rng.uniform(0.006, min(0.02, cell / 10)),
                           depth_m=rng.uniform(0.003, 0.012))

    def generate(self, params: "Alligator.Params", rng: np.random.Generator, name: str) -> DefectModel:
        owner = f"defect type {self.name}"
        p = check_params(params, owner)
        if p.cell_m > min(p.length_m, p.width_m) / 2:
            raise RoadtwinError(f"{owner}: parameter cell_m ({p.cell_m}) must be <= half of min(length_m, width_m)")
        if p.groove_m > p.cell_m / 8:
            raise RoadtwinError(f"{owner}: parameter groove_m ({p.groove_m}) must be <= cell_m / 8")
        w, D = p.groove_m, p.depth_m
        spacing = float(np.clip(0.6 * w, 0.004, 0.015))  # loop spacing along the grooves
        clearance = w + 1.5 * spacing                   # gaps between grooves stay >= 1.5 loop spacings
        lines = cell_tree(rng, p.length_m, p.width_m, p.cell_m, p.jitter, 1.4 * clearance, clearance)
        return groove_network(lines, w, D, spacing, name=name, defect_type=self.name, params=p)


def cell_tree(rng: np.random.Generator, length: float, width: float, cell: float, jitter: float,
              gap: float, clearance: float) -> list[np.ndarray]:
    """The cell edges inside the ellipse (length x width, long axis +x) as 2-point segments that
    form a tree: a spanning tree of the edge graph from the vertex nearest the centre, and each
    other edge shortened by ``gap`` at one end (its far end from the tree's root); a stub whose
    tip still comes within ``clearance`` of another groove (a sharp cell corner) is left out."""
    a, b = length / 2, width / 2
    row = cell * np.sqrt(3) / 2
    ys = np.arange(-b - 2 * row, b + 2 * row + 1e-9, row)
    xs = np.arange(-a - 2 * cell, a + 2 * cell + 1e-9, cell)
    seeds = np.array([(x + (cell / 2 if k % 2 else 0.0), y) for k, y in enumerate(ys) for x in xs])
    seeds = seeds + rng.uniform(-jitter, jitter, seeds.shape) * cell
    vor = Voronoi(seeds)
    v, ridges = merge_close_vertices(vor.vertices, [e for e in vor.ridge_vertices if -1 not in e], clearance)
    inside = (v[:, 0] / a) ** 2 + (v[:, 1] / b) ** 2 <= 1.0
    edges = sorted({tuple(sorted(e)) for e in ridges if inside[e[0]] and inside[e[1]]})
    if not edges:
        raise RoadtwinError("defect type alligator: no cell edge inside the area (cell_m too large)")
    adj: dict[int, list[int]] = {}
    for i, j in edges:
        adj.setdefault(i, []).append(j)
        adj.setdefault(j, []).append(i)
    root = min(adj, key=lambda k: float(np.hypot(*v[k])))
    order = {root: 0}
    queue, tree = deque([root]), set()
    while queue:
        i = queue.popleft()
        for j in sorted(adj[i]):
            if j not in order:
                order[j] = len(order)
                tree.add((min(i, j), max(i, j)))
                queue.append(j)
    lines, stubs = [], []
    for i, j in edges:
        if i not in order:                      # a piece cut off from the middle by the clipping
            continue
        if (i, j) in tree:
            lines.append(v[[i, j]])
            continue
        near, far = (i, j) if order[i] < order[j] else (j, i)
        seg = v[far] - v[near]
        keep = float(np.hypot(*seg)) - gap
        if keep > gap / 2:                      # a stub shorter than that would be a speck
            stubs.append(np.array([v[near], v[near] + seg * keep / np.hypot(*seg)]))
    kept = list(lines)
    for k, stub in enumerate(stubs):
        others = MultiLineString([LineString(c) for c in lines + stubs[:k] + stubs[k + 1:]])
        if others.distance(Point(stub[1])) >= clearance:
            kept.append(stub)
    return kept


def merge_close_vertices(vertices: np.ndarray, ridges: list, tol: float) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Vertices joined by an edge shorter than ``tol`` become one (their mean), and that edge goes:
    jittered seeds leave near-degenerate Voronoi corners whose grooves would touch across a tiny
    edge, closing a cell the tree was meant to leave open."""
    parent = list(range(len(vertices)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in ridges:
        if np.hypot(*(vertices[i] - vertices[j])) < tol:
            parent[root(i)] = root(j)
    roots = np.array([root(i) for i in range(len(vertices))])
    merged = vertices.copy()
    for r in np.unique(roots):
        members = roots == r
        merged[members] = vertices[members].mean(axis=0)
    edges = sorted({tuple(sorted((int(roots[i]), int(roots[j])))) for i, j in ridges if roots[i] != roots[j]})
    return merged, edges
