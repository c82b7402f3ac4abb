"""COCO instances: ``instance/000000.png`` (uint16 instance ids, 0 = none; ids in meta.json
"instances") and ``coco/annotations/instances_train.json`` (RLE masks, file_name relative to the
output directory). COCO RLE is encoded here (pycocotools' compressed string format, column-major
runs starting with zeros), so writing needs no pycocotools; ``rle_decode`` reads it back."""
from __future__ import annotations

import json

import numpy as np

from .images import save_png

__all__ = ["CocoWriter", "rle_decode", "rle_encode"]


def rle_encode(mask: np.ndarray) -> dict:
    """Binary (H, W) mask -> COCO compressed RLE ``{"size": [H, W], "counts": str}``."""
    m = np.asarray(mask, dtype=bool)
    h, w = m.shape
    flat = m.ravel(order="F").astype(np.int8)
    change = np.flatnonzero(np.diff(flat)) + 1
    bounds = np.concatenate([[0], change, [flat.size]])
    counts = np.diff(bounds).tolist()
    if flat.size and flat[0] == 1:
        counts = [0] + counts
    if flat.size == 0:
        counts = [0]
    return {"size": [int(h), int(w)], "counts": _counts_to_string(counts)}


def _counts_to_string(counts: list[int]) -> str:
    out = []
    for i, c in enumerate(counts):
        x = int(c)
        if i > 2:
            x -= int(counts[i - 2])
        more = True
        while more:
            ch = x & 0x1F
            x >>= 5
            more = (x != -1) if (ch & 0x10) else (x != 0)
            if more:
                ch |= 0x20
            out.append(chr(ch + 48))
    return "".join(out)


def _string_to_counts(s: str) -> list[int]:
    counts: list[int] = []
    p = 0
    while p < len(s):
        x, k, more = 0, 0, True
        while more:
            c = ord(s[p]) - 48
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p += 1
            k += 1
            if not more and (c & 0x10):
                x |= -1 << (5 * k)
        if len(counts) > 2:
            x += counts[-2]
        counts.append(x)
    return counts


def rle_decode(rle: dict) -> np.ndarray:
    """COCO RLE (compressed string or uncompressed list counts) -> uint8 (H, W) mask."""
    h, w = rle["size"]
    counts = rle["counts"]
    if isinstance(counts, (bytes, str)):
        counts = _string_to_counts(counts.decode() if isinstance(counts, bytes) else counts)
    counts = np.asarray(counts, dtype=np.int64)
    if counts.sum() != h * w:
        raise ValueError(f"RLE counts sum to {counts.sum()}, mask has {h * w} pixels")
    values = np.arange(len(counts)) % 2
    flat = np.repeat(values, counts).astype(np.uint8)
    return flat.reshape((w, h)).T.copy()



class CocoWriter:
    name = "coco"
    needs_stereo = False

    def __init__(self, ds) -> None:
        self.ds = ds
        self.images: list[dict] = []
        self.annotations: list[dict] = []
        for d in ("coco/annotations", "instance"):
            (ds.root / d).mkdir(parents=True, exist_ok=True)

    def add(self, k: int, stem: str, frame, files: dict) -> dict:
        return self.commit(k, self.write(k, stem, frame, files))

    def write(self, k: int, stem: str, frame, files: dict) -> tuple[dict, list[dict]]:
        """The instance PNG and the frame's image entry and annotations, ids not yet given
        (thread-safe: touches nothing shared; :meth:`commit` numbers them in frame order)."""
        ds = self.ds
        inst = frame.instance.astype(np.int64)
        save_png(ds.root / "instance" / f"{stem}.png", inst.astype(np.uint16))
        files["instance"] = f"instance/{stem}.png"
        h, w = inst.shape
        image = {"id": k + 1, "file_name": files["rgb"], "width": w, "height": h}
        annotations = []
        ids, counts = np.unique(inst[inst > 0], return_counts=True)
        for iid, n in zip(ids.tolist(), counts.tolist()):
            if n < ds.min_instance_pixels:
                continue
            meta = ds.instances[iid - 1]
            mask = inst == iid
            ys, xs = np.nonzero(mask)
            annotations.append({
                "image_id": k + 1, "category_id": ds.categories.index(meta["type"]) + 1,
                "segmentation": rle_encode(mask), "area": int(n),
                "bbox": [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)],
                "iscrowd": 0, "instance_id": iid, "defect_id": meta["defect_id"]})
        return image, annotations

    def commit(self, k: int, state: tuple[dict, list[dict]]) -> dict:
        image, annotations = state
        self.images.append(image)
        for a in annotations:
            self.annotations.append({"id": len(self.annotations) + 1, **a})
        return {"instances_visible": [a["instance_id"] for a in annotations]}

    def finish(self) -> None:
        coco = {"info": {"description": "roadtwin synthetic road defects", "version": "1.0"},
                "licenses": [], "images": self.images, "annotations": self.annotations,
                "categories": [{"id": i + 1, "name": n, "supercategory": "road_defect"}
                               for i, n in enumerate(self.ds.categories)]}
        (self.ds.root / "coco/annotations/instances_train.json").write_text(json.dumps(coco))
