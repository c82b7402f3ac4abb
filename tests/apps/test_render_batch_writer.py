"""The dataset writer's two halves: ``write`` (files, on any thread, any order) and ``commit``
(records, in frame order) give what ``add`` gives frame by frame."""
from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from roadtwin_core import RoadtwinError
from roadtwin_core.apps.render.writers import DatasetWriter
from roadtwin_core.render import Camera, Frame, Intrinsics, look_from

K = Intrinsics.from_fov(24, 16, 90.0)
INSTANCES = [{"type": "pothole", "defect_id": "p0"}, {"type": "crack", "defect_id": "c0"}]


def _frame(i: int) -> tuple[Frame, np.ndarray]:
    """Frame i: instance 1 in a block that moves with i, instance 2 only in odd frames."""
    rng = np.random.default_rng(i)
    inst = np.zeros((16, 24), np.int32)
    inst[2:6, i:i + 5] = 1
    if i % 2:
        inst[10:14, 3:9] = 2
    cam = Camera(K, look_from([0.0, float(i), 1.5], 0.1 * i, -0.2))
    frame = Frame(index=i, camera=cam, depth=rng.uniform(1, 50, (16, 24)).astype(np.float32),
                  semantic=(inst > 0).astype(np.uint8) * 2, instance=inst,
                  normal=np.zeros((16, 24, 3), np.float32))
    return frame, rng.integers(0, 256, (16, 24, 3), dtype=np.uint8)


def _writer(root):
    return DatasetWriter(root, ["mmseg", "coco", "depth", "normal"], K, ["background", "driving", "pothole"],
                         INSTANCES, categories=["pothole", "crack"])


def _tree(root) -> dict:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_threaded_writes_committed_in_order_equal_frame_by_frame_adds(tmp_path):
    frames = [_frame(i) for i in range(7)]
    one = _writer(tmp_path / "one")
    for i, (f, rgb8) in enumerate(frames):
        one.add(f, rgb8, record={"i": i})
    one.finish()
    many = _writer(tmp_path / "many")
    with ThreadPoolExecutor(4) as pool:        # written in reverse order, on 4 threads
        futures = {i: pool.submit(many.write, i, f, rgb8) for i, (f, rgb8) in reversed(list(enumerate(frames)))}
        for i in range(len(frames)):
            many.commit(futures[i].result(), {"i": i})
    many.finish()
    assert _tree(tmp_path / "one") == _tree(tmp_path / "many")
    coco = json.loads((tmp_path / "many/coco/annotations/instances_train.json").read_text())
    # 7 frames with instance 1, 3 odd ones with instance 2: ids numbered in frame order
    assert [(a["id"], a["image_id"], a["instance_id"]) for a in coco["annotations"]][:4] == \
        [(1, 1, 1), (2, 2, 1), (3, 2, 2), (4, 3, 1)]


def test_a_frame_committed_out_of_order_is_an_error(tmp_path):
    w = _writer(tmp_path / "w")
    written = [w.write(i, *_frame(i)) for i in range(2)]
    with pytest.raises(RoadtwinError, match="out of order"):
        w.commit(written[1])
