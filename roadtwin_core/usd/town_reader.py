"""Read a composed town stage back into numpy: what renderers, physics backends and planners
consume (they never need to walk USD themselves).

Colliders are the meshes the physics layer gives ``UsdPhysics.CollisionAPI``: the same road and
defect meshes that are rendered (read once, shared arrays), whatever their visibility.
Rendered meshes are the road segments, the defect pieces and the lane markings (meshes under a
prim carrying ``roadtwin:marking:type``, i.e. ``/<root>/Markings/<id>``). With ``looks=True``
each of them also gets its texture coordinates (``TownMesh.st``, per face corner) and its bound
``UsdPreviewSurface`` material (``TownMesh.material``, see :mod:`.looks_reader`); physics and
planning leave ``looks`` off, so a broken texture path never stops them.

Props (``layers/props.usda``) are read too: each ``UsdGeom.PointInstancer`` is expanded into one
world-space mesh per prototype part (``TownScene.props``, kind = the prototype's class label) and
its instances' positions are kept (``TownScene.instances``: the view sampler keeps cameras off
the vehicles standing in lanes); a Mesh with a prop label (:data:`PROP_LABELS`), the terrain, is a
prop as it is. Props are not colliders.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom, UsdPhysics, UsdSemantics

from ..errors import RoadtwinError
from ..town.prop_shapes import PROP_LABELS
from .looks_reader import TownMaterial, bound_material, corner_st
from .checks import FaceBudget, open_stage
from .stage import read_mesh


@dataclass
class TownMesh:
    path: str
    kind: str                 # road segment kind ("driving", "sidewalk" ...), marking type or "collision"
    vertices: np.ndarray      # (N,3) world
    faces: np.ndarray         # (M,3)
    st: np.ndarray | None = None              # (M,3,2) texture coordinates per face corner (looks=True)
    material: TownMaterial | None = None      # bound material (looks=True; None = unbound)


@dataclass
class TownDefect:
    id: str
    defect_type: str
    attributes: dict
    pieces: list[TownMesh]    # one baked mesh per segment the defect lies on

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        return concat_meshes(self.pieces)


@dataclass
class TownInstances:
    """The instances of one ``UsdGeom.PointInstancer`` (props): where they stand and what they are."""

    path: str
    place: str                # roadtwin:prop:place of the instancer (roadside, chain, lane, far; "" unknown)
    labels: np.ndarray        # (N,) class label of each instance's prototype
    positions: np.ndarray     # (N,3) world position of each instance's origin
    radii: np.ndarray         # (N,) plan radius about the origin that holds the instance (scaled prototype)
    corners: np.ndarray | None = None   # (N,4,2) world plan corners of each instance's prototype bounding box


@dataclass
class TownScene:
    name: str
    source: str
    roads: list[TownMesh] = field(default_factory=list)
    defects: list[TownDefect] = field(default_factory=list)
    colliders: list[TownMesh] = field(default_factory=list)
    markings: list[TownMesh] = field(default_factory=list)   # kind = roadtwin:marking:type
    props: list[TownMesh] = field(default_factory=list)      # kind = semantic label (vegetation, pole ...):
                                                             # PointInstancers expanded, plus labelled prop meshes
    instances: list[TownInstances] = field(default_factory=list)   # per PointInstancer: its instances
    metadata: dict = field(default_factory=dict)

    def collision_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """All static colliders as one triangle mesh (road with the defects baked in)."""
        if not self.colliders:
            raise RoadtwinError(f"{self.source}: stage has no collision mesh (compose it with roadtwin first)")
        return concat_meshes(self.colliders)

    def defect(self, defect_id: str) -> TownDefect:
        for d in self.defects:
            if d.id == defect_id:
                return d
        raise RoadtwinError(f"{self.source}: no defect {defect_id!r} (known: {', '.join(d.id for d in self.defects[:10])}...)")


def concat_meshes(meshes: list[TownMesh]) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, offset = [], [], 0
    for m in meshes:
        verts.append(m.vertices)
        faces.append(m.faces + offset)
        offset += len(m.vertices)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def load_town(path: str | Path, looks: bool = False, variants: dict[str, str] | None = None) -> TownScene:
    """The town's meshes (world space). ``looks``: also read each rendered mesh's bound material
    and st (see :mod:`.looks_reader`). ``variants``: variant selections on the root prim (e.g.
    ``{"roadMaterial": "cobblestone"}``), made in the session layer, never saved."""
    path = Path(path)
    stage = open_stage(path, "USD town stage")
    budget = FaceBudget(path)
    root = stage.GetDefaultPrim()
    for vset, choice in (variants or {}).items():
        _select_variant(stage, root, vset, choice, path)
    scene = TownScene(root.GetName(), str(path))
    scene.metadata = {a.GetName().split(":", 2)[-1]: a.Get() for a in root.GetAttributes()
                      if a.GetName().startswith(("roadtwin:layout:", "roadtwin:compose:"))}
    defects: dict[str, TownDefect] = {}
    marking_types: dict[str, str] = {}
    materials: dict = {}
    it = iter(Usd.PrimRange(root))
    for prim in it:
        if prim.IsA(UsdGeom.PointInstancer):
            it.PruneChildren()   # prototypes are drawn through their instancer only
            if UsdGeom.Imageable(prim).ComputeVisibility() != UsdGeom.Tokens.invisible:
                meshes, instances = expand_instancer(prim, budget, looks, materials)
                scene.props += meshes
                scene.instances.append(instances)
            continue
        if prim.HasAttribute("roadtwin:defect:type") and prim.IsA(UsdGeom.Xform):
            attrs = {a.GetName().split(":")[-1]: a.Get() for a in prim.GetAttributes()
                     if a.GetName().startswith("roadtwin:defect:")}
            defects[str(prim.GetPath())] = TownDefect(prim.GetName(), str(attrs.get("type")), attrs, [])
            continue
        marking = prim.GetAttribute("roadtwin:marking:type")
        if marking and marking.HasValue():
            marking_types[str(prim.GetPath())] = str(marking.Get())
        if not prim.IsA(UsdGeom.Mesh):
            if prim.HasAttribute("roadtwin:segment:kind"):
                raise RoadtwinError(f"{path}: segment {prim.GetPath()} is a {prim.GetTypeName() or 'typeless prim'}, "
                                    "expected a Mesh")
            continue
        mesh = UsdGeom.Mesh(prim)
        v = f = None
        if prim.HasAPI(UsdPhysics.CollisionAPI):  # the road and defect meshes themselves (physics.usda)
            v, f = read_mesh(mesh, budget=budget)
            scene.colliders.append(TownMesh(str(prim.GetPath()), "collision", v, f))
        if prim.HasAttribute("roadtwin:segment:kind"):
            target, kind = scene.roads, str(prim.GetAttribute("roadtwin:segment:kind").Get())
        elif str(prim.GetParent().GetPath()) in defects:
            target, kind = defects[str(prim.GetParent().GetPath())].pieces, None
        else:
            kind = _marking_type(prim, marking_types)
            if kind is None:
                kind = prop_label(prim)
                if kind is None:
                    continue
                target = scene.props
            else:
                target = scene.markings
        if UsdGeom.Imageable(prim).ComputeVisibility() == UsdGeom.Tokens.invisible:
            continue
        if v is None:
            v, f = read_mesh(mesh, budget=budget)
        if kind is None:
            kind = defects[str(prim.GetParent().GetPath())].defect_type
        tm = TownMesh(str(prim.GetPath()), kind, v, f)
        if looks:
            tm.material, tm.st = _looks(prim, mesh, len(f), materials)
        target.append(tm)
    scene.defects = list(defects.values())
    return scene


def prop_label(prim) -> str | None:
    """The first ``class`` label of the prim or its nearest labelled ancestor, when it is a prop
    label (:data:`PROP_LABELS`); None otherwise (roads, defects and markings are read by kind)."""
    p = prim
    while p and not p.IsPseudoRoot():
        if p.HasAPI(UsdSemantics.LabelsAPI, "class"):
            labels = UsdSemantics.LabelsAPI(p, "class").GetLabelsAttr().Get() or []
            return str(labels[0]) if len(labels) and str(labels[0]) in PROP_LABELS else None
        p = p.GetParent()
    return None


def expand_instancer(prim, budget: FaceBudget, looks: bool, materials: dict) -> tuple[list[TownMesh], TownInstances]:
    """A PointInstancer as world-space meshes: one TownMesh per prototype part, holding every
    instance of it (kind = the prototype's label, ``prop`` when it has none), and its instances'
    positions and labels. The expanded triangles count against the face budget (a prototype
    stored once is drawn once per instance)."""
    inst = UsdGeom.PointInstancer(prim)
    idx = np.asarray(inst.GetProtoIndicesAttr().Get() or [], dtype=np.int64)
    xf = inst.ComputeInstanceTransformsAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default())
    mats = np.asarray(xf, dtype=np.float64).reshape(-1, 4, 4)
    if len(mats) != len(idx):
        raise RoadtwinError(f"{prim.GetPath()}: PointInstancer transforms do not match its protoIndices "
                            f"({len(mats)} transforms, {len(idx)} indices)")
    if len(mats):
        mats = mats @ np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
        if not np.isfinite(mats).all():
            raise RoadtwinError(f"{prim.GetPath()}: PointInstancer transforms have NaN or infinite entries")
    place = prim.GetAttribute("roadtwin:prop:place")
    labels = np.full(len(idx), "prop", dtype=object)
    reach = np.zeros(len(idx))      # each instance's prototype: its farthest plan point from the origin
    box = np.full((len(inst.GetPrototypesRel().GetTargets()), 4), np.nan)   # each prototype's plan box x0, y0, x1, y1
    out = []
    for k, target in enumerate(inst.GetPrototypesRel().GetTargets()):
        proto = prim.GetStage().GetPrimAtPath(target)
        mine = mats[idx == k]
        if not proto or not len(mine):
            continue
        label = prop_label(proto) or "prop"
        labels[idx == k] = label
        for part in Usd.PrimRange(proto):
            if not part.IsA(UsdGeom.Mesh):
                continue
            mesh = UsdGeom.Mesh(part)
            v, f = read_mesh(mesh, world=False, budget=budget)
            budget.take(len(f) * (len(mine) - 1), f"{prim.GetPath()} ({len(mine)} instances of {part.GetPath()})")
            if part != proto:   # the part's transform relative to its prototype root
                rel = np.asarray(UsdGeom.Xformable(part).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
                base = np.asarray(UsdGeom.Xformable(proto).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
                m = rel @ np.linalg.inv(base)
                v = v @ m[:3, :3] + m[3, :3]
            if len(v):
                reach[idx == k] = np.maximum(reach[idx == k], np.hypot(v[:, 0], v[:, 1]).max())
                box[k] = np.r_[np.fmin(box[k, :2], v[:, :2].min(0)), np.fmax(box[k, 2:], v[:, :2].max(0))]
            n = len(mine)
            world = np.einsum("vj,njk->nvk", v, mine[:, :3, :3]) + mine[:, None, 3, :3]
            faces = (f[None] + (np.arange(n) * len(v))[:, None, None]).reshape(-1, 3)
            tm = TownMesh(f"{part.GetPath()}", label, world.reshape(-1, 3), faces)
            if looks:
                tm.material, st = _looks(part, mesh, len(f), materials)
                tm.st = None if st is None else np.tile(st, (n, 1, 1))
            out.append(tm)
    positions = mats[:, 3, :3] if len(mats) else np.zeros((0, 3))
    scale = np.linalg.norm(mats[:, :2, :3], axis=2).max(axis=1) if len(mats) else np.zeros(0)
    corners = np.zeros((len(idx), 4, 2))
    if len(mats):
        x0, y0, x1, y1 = np.nan_to_num(box[idx]).T           # (N,) each, prototype space (no mesh: its origin)
        local = np.stack([np.stack([x0, y0], 1), np.stack([x1, y0], 1), np.stack([x1, y1], 1), np.stack([x0, y1], 1)], 1)
        corners = np.einsum("nkj,njl->nkl", local, mats[:, :2, :2]) + mats[:, None, 3, :2]
    return out, TownInstances(str(prim.GetPath()), str(place.Get()) if place and place.HasValue() else "",
                              labels.astype(str), positions, reach * scale, corners)


def _marking_type(prim, marking_types: dict[str, str]) -> str | None:
    """The ``roadtwin:marking:type`` of the prim or its nearest ancestor that has one."""
    p = prim
    while p and not p.IsPseudoRoot():
        t = marking_types.get(str(p.GetPath()))
        if t is not None:
            return t
        p = p.GetParent()
    return None


def _looks(prim, mesh: UsdGeom.Mesh, n_faces: int, materials: dict):
    mat = bound_material(prim, materials)
    name = mat.st_name if mat is not None else "st"
    st = corner_st(mesh, name, np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64))
    if st is None and mat is not None and mat.textured:
        raise RoadtwinError(f"{prim.GetPath()}: bound to textured material {mat.name} but has no primvars:{name}")
    if st is not None and len(st) != n_faces:
        raise RoadtwinError(f"{prim.GetPath()}: primvars:{name} does not match the mesh's faces")
    return mat, st


def _select_variant(stage, root, vset: str, choice: str, path: Path) -> None:
    sets = root.GetVariantSets()
    if not sets.HasVariantSet(vset):
        raise RoadtwinError(f"{path}: the root prim {root.GetPath()} has no {vset!r} variant set "
                            f"(has: {', '.join(sets.GetNames()) or 'none'})")
    names = sets.GetVariantSet(vset).GetVariantNames()
    if choice not in names:
        raise RoadtwinError(f"{path}: {vset} variant {choice!r} is not one of {', '.join(names)}")
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        sets.GetVariantSet(vset).SetVariantSelection(choice)
