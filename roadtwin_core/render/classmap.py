"""Class maps: roadtwin's semantic labels -> a dataset's classes, from a small TOML file.

A rendered frame's semantic image holds roadtwin label ids (``background``, ``driving``,
``sidewalk``, ``pothole``, ``crack`` ... as ``scene.class_names`` lists them; 255 ignore). A
dataset (e.g. the real road_defects_br frames) has its own classes, some of which roadtwin has
no label for: the *ego lane* is the lane the camera drives in, a property of the frame, not of
the road. A class map says, in TOML::

    name = "road_defects_br"
    classes = ["background", "ego_lane", "crack", "pothole"]   # dataset ids 0, 1, 2, 3
    unknown = "background"          # a stage label no entry names -> this class, or "ignore"
    optional = ["lane_marking"]     # named labels a stage may lack
    [map]
    background = ["background", "driving", "sidewalk"]
    ego_lane = {from = ["driving", "lane_marking"], rule = "ego"}
    crack = ["crack"]
    pothole = ["pothole"]
    [dilate_px]
    crack = 1                       # grow crack pixels by 1 px (see below)

Resolution per pixel: where the frame's ego mask is set and the pixel's label is listed under an
``rule = "ego"`` class, that class; otherwise the class whose plain list holds the label;
otherwise ``unknown``; roadtwin's ignore (255) stays 255. Each pixel has a single label, so
defects override the lane simply by not being listed under the ego class. Without an ego mask
(``ego=None``) the ego classes get no pixels. A label listed twice (two plain or two ego
entries) is an error, so the mapping never depends on the file's order.

``[dilate_px]`` (optional) grows a class's pixels by that many pixels after mapping
(:meth:`ClassMap.spread`), over pixels of classes listed *before* it only (never over ignore):
with classes in the real labels' order this keeps "pothole over crack over lane". Why: a real
crack label marks the cracked area as an annotator drew it (road_defects_br: strokes about 2 px
wide at 512x320, from 2x2 max pooling of 1024x640 masks), while a ray cast samples a 1-3 cm
groove at pixel centres and leaves a broken 1-px line; growing it by 1 px gives the same stroke
width (measured on the real train labels: median 2A/P of crack components 2.06 px).

``[label_range_m]`` (optional) sets a class's pixels deeper than that many metres (z-depth) to
ignore after growing (:meth:`ClassMap.within_range`): a survey's annotators label defects only so
far ahead (road_defects_br: bench/defect_priors.py measures where the train labels end), and a
far defect labelled where the real frames leave it unlabelled teaches the opposite of them.

Built-in maps ship as package data in ``roadtwin_core/render/classmaps/`` and are loaded by
name (``load_class_map("road_defects_br")``). Needs Python 3.11+ (``tomllib``) and numpy only.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import RoadtwinError
from .scene import IGNORE_INDEX

RULES = ("ego",)


@dataclass(frozen=True)
class ClassMap:
    name: str
    classes: tuple[str, ...]                      # dataset classes, id = position
    plain: dict[str, str]                         # roadtwin label -> dataset class
    ego: dict[str, str]                           # roadtwin label -> dataset class inside the ego mask
    unknown: str | None                           # dataset class, or None = ignore
    optional: frozenset[str] = frozenset()
    source: str = "<class map>"                   # the file, for messages
    dilate_px: tuple[tuple[str, int], ...] = ()   # (dataset class, pixels) grown after mapping
    camera_targets: str | None = None             # camera targets (randomize.Ranges.from_targets) for --randomize
    label_range_m: tuple[tuple[str, float], ...] = ()   # (dataset class, metres of z-depth) labelled up to

    @property
    def labels(self) -> list[str]:
        """Every roadtwin label the map names (sorted)."""
        return sorted(set(self.plain) | set(self.ego))

    @property
    def num_classes(self) -> int:
        return len(self.classes)

    def check_labels(self, stage_labels: Sequence[str], where: str = "the stage") -> None:
        """Raise if the map names a label ``where`` lacks (``optional`` ones excepted)."""
        have = set(stage_labels)
        for label in self.labels:
            if label not in have and label not in self.optional:
                raise RoadtwinError(f"{self.source}: class map names label {label!r}, which {where} lacks "
                                    f"(its labels: {', '.join(stage_labels)})")

    def lookup_tables(self, stage_labels: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """Two 256-entry uint8 tables, stage label id -> dataset id: outside and inside the ego mask."""
        if len(stage_labels) > IGNORE_INDEX:
            raise RoadtwinError(f"{len(stage_labels)} stage labels do not fit uint8 (255 is the ignore index)")
        cid = {c: i for i, c in enumerate(self.classes)}
        fallback = IGNORE_INDEX if self.unknown is None else cid[self.unknown]
        plain = np.full(256, IGNORE_INDEX, dtype=np.uint8)
        for i, label in enumerate(stage_labels):
            plain[i] = cid[self.plain[label]] if label in self.plain else fallback
        inside = plain.copy()
        for i, label in enumerate(stage_labels):
            if label in self.ego:
                inside[i] = cid[self.ego[label]]
        return plain, inside

    def apply(self, labels: np.ndarray, stage_labels: Sequence[str], ego: np.ndarray | None = None) -> np.ndarray:
        """Stage label ids (uint8 array, 255 ignore) -> dataset class ids (uint8, 255 ignore).

        ``ego``: boolean array of the same shape, True where the camera's own lane is (the
        renderer derives it from the lane id under each pixel), or None."""
        labels = np.asarray(labels)
        if labels.size and labels.min() < 0:
            raise RoadtwinError(f"{self.source}: negative label ids")
        bad = (labels >= len(stage_labels)) & (labels != IGNORE_INDEX)
        if bad.any():
            raise RoadtwinError(f"{self.source}: label id {int(labels[bad].flat[0])} outside the stage's "
                                f"{len(stage_labels)} labels")
        plain, inside = self.lookup_tables(stage_labels)
        idx = labels.astype(np.intp)
        out = plain[idx]
        if ego is not None:
            ego = np.asarray(ego, dtype=bool)
            if ego.shape != labels.shape:
                raise RoadtwinError(f"ego mask shape {ego.shape} differs from the labels' {labels.shape}")
            out = np.where(ego, inside[idx], out)
        return out


    def within_range(self, mapped: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """``mapped`` with the ``label_range_m`` classes' pixels deeper than their range set to
        ignore (255): a survey's annotators labelled defects only so far ahead (road_defects_br:
        99 % of crack pixels within 8.3 m, of pothole pixels within 14.8 m of z-depth,
        bench/defect_priors.py), and a far defect labelled where the real frames leave it
        unlabelled teaches the opposite of them.
        Ignore, not background: the look of a far defect is neither taught nor untaught."""
        if not self.label_range_m:
            return mapped
        depth = np.asarray(depth)
        if depth.shape != mapped.shape:
            raise RoadtwinError(f"depth shape {depth.shape} differs from the labels' {mapped.shape}")
        out = mapped.copy()
        for name, metres in self.label_range_m:
            out[(mapped == self.classes.index(name)) & (depth > metres)] = IGNORE_INDEX
        return out

    def spread(self, mapped: np.ndarray) -> np.ndarray:
        """Grow the ``dilate_px`` classes of mapped labels (dataset ids) by their radius, over
        pixels of earlier classes only (a disc-like kernel: cv2's ellipse of 2r+1)."""
        if not self.dilate_px:
            return mapped
        import cv2

        out = np.array(mapped, dtype=np.uint8, copy=True)
        cid = {c: i for i, c in enumerate(self.classes)}
        for name, r in self.dilate_px:
            k = cid[name]
            mask = (out == k).astype(np.uint8)
            if r <= 0 or not mask.any():
                continue
            grown = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))).astype(bool)
            out[grown & (out < k)] = k
        return out


# ------------------------------------------------------------------------------------ loading
def builtin_class_maps() -> list[str]:
    """Names of the class maps shipped with roadtwin."""
    return sorted(p.name[:-5] for p in resources.files(__package__).joinpath("classmaps").iterdir()
                  if p.name.endswith(".toml"))


def load_class_map(spec: str | Path) -> ClassMap:
    """A class map from a TOML file path, or a built-in one by name (``road_defects_br``)."""
    path = Path(spec)
    if path.suffix != ".toml" and not path.exists():
        res = resources.files(__package__).joinpath("classmaps", f"{spec}.toml")
        if not res.is_file():
            raise RoadtwinError(f"no class map {str(spec)!r}: not a file, nor a built-in one "
                                f"({', '.join(builtin_class_maps())})")
        return parse_class_map(res.read_text(encoding="utf-8"), source=f"{spec} (built-in)")
    if path.is_dir():
        raise RoadtwinError(f"{path}: is a directory, not a class map file")
    if not path.is_file():
        raise RoadtwinError(f"{path}: no such class map file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RoadtwinError(f"{path}: cannot read the class map ({exc})") from None
    return parse_class_map(text, source=str(path))


def _class_table(data: dict, key: str, unit: str, classes: list[str], source: str, valid, wanted: str) -> tuple:
    """An optional ``[key]`` table of class = number, checked (one line naming the entry), as
    (class, value) pairs in the classes' order."""
    table = data.get(key, {})
    if not isinstance(table, dict):
        raise RoadtwinError(f"{source}: [{key}] must be a table of class = {unit}")
    for cls, value in table.items():
        if cls not in classes:
            raise RoadtwinError(f"{source}: [{key}] entry {cls!r} is not one of the classes ({', '.join(classes)})")
        if not valid(value):
            raise RoadtwinError(f"{source}: [{key}] {cls} must be {wanted}, got {value!r}")
    return tuple(sorted(table.items(), key=lambda kv: classes.index(kv[0])))


def _names(value, what: str, source: str) -> list[str]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) and v for v in value):
        raise RoadtwinError(f"{source}: {what} must be a non-empty list of label names")
    return value


def parse_class_map(text: str, source: str = "<class map>") -> ClassMap:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RoadtwinError(f"{source}: not valid TOML ({exc})") from None
    known_keys = {"name", "classes", "unknown", "optional", "map", "dilate_px", "camera_targets", "label_range_m"}
    extra = sorted(set(data) - known_keys)
    if extra:
        raise RoadtwinError(f"{source}: unknown key {extra[0]!r} (known: {', '.join(sorted(known_keys))})")
    classes = data.get("classes")
    if not isinstance(classes, list) or not classes or not all(isinstance(c, str) and c for c in classes):
        raise RoadtwinError(f"{source}: 'classes' must be a non-empty list of class names")
    if len(set(classes)) != len(classes):
        raise RoadtwinError(f"{source}: 'classes' lists a class twice")
    if len(classes) > IGNORE_INDEX:
        raise RoadtwinError(f"{source}: {len(classes)} classes do not fit uint8 (255 is the ignore index)")
    unknown = data.get("unknown", "ignore")
    if unknown != "ignore" and unknown not in classes:
        raise RoadtwinError(f"{source}: unknown = {unknown!r} is neither a class nor \"ignore\"")
    mapping = data.get("map")
    if not isinstance(mapping, dict) or not mapping:
        raise RoadtwinError(f"{source}: no [map] table")
    plain: dict[str, str] = {}
    ego: dict[str, str] = {}
    for cls, entry in mapping.items():
        if cls not in classes:
            raise RoadtwinError(f"{source}: [map] entry {cls!r} is not one of the classes ({', '.join(classes)})")
        target = plain
        if isinstance(entry, dict):
            rule = entry.get("rule")
            if rule not in RULES:
                raise RoadtwinError(f"{source}: [map] {cls}: rule {rule!r} unknown (known: {', '.join(RULES)})")
            if set(entry) - {"from", "rule"}:
                raise RoadtwinError(f"{source}: [map] {cls}: keys are 'from' and 'rule'")
            labels = _names(entry.get("from"), f"[map] {cls}.from", source)
            target = ego
        else:
            labels = _names(entry, f"[map] {cls}", source)
        for label in labels:
            if label in target:
                raise RoadtwinError(f"{source}: label {label!r} is mapped twice ({target[label]} and {cls})")
            target[label] = cls
    optional = data.get("optional", [])
    if optional:
        optional = _names(optional, "'optional'", source)
    dilate = _class_table(data, "dilate_px", "pixels", classes, source,
                          lambda v: isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 16,
                          "an integer number of pixels in 0..16")
    ranges = _class_table(data, "label_range_m", "metres", classes, source,
                          lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < 1e4,
                          "a distance in metres > 0")
    targets = data.get("camera_targets")
    if targets is not None and not (isinstance(targets, str) and targets):
        raise RoadtwinError(f"{source}: camera_targets must be the name or path of a camera targets file")
    return ClassMap(name=str(data.get("name", Path(source).stem)), classes=tuple(classes), plain=plain, ego=ego,
                    camera_targets=targets,
                    unknown=None if unknown == "ignore" else unknown, optional=frozenset(optional), source=source,
                    dilate_px=dilate, label_range_m=tuple((c, float(m)) for c, m in ranges))
