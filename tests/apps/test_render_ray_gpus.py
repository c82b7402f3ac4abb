"""`--executor ray` on GPUs (issue 21): one contiguous shard of frames a GPU of the cluster.

No GPU here: a local Ray cluster declares two fake GPUs and the sharded path is forced on the
CPU device, so each shard's task renders on the CPU with its own ``CUDA_VISIBLE_DEVICES``. The
reference is the serial executor's output (one process, frame i from (seed, i) alone).
"""
from __future__ import annotations

import time

import pytest

from roadtwin_core import RoadtwinError
from roadtwin_core.apps.render import RenderOptions, run_render
from roadtwin_core.apps.render import gpu_shards
from roadtwin_core.apps.render.frame_sink import FrameSink
from roadtwin_core.apps.render.writers import DatasetWriter
from test_render_batch_writer import _frame, _tree, _writer
from test_render_dataset import assert_same_dataset, pm, road  # noqa: F401  (fixtures: plugins, a road with defects)

def _options(executor: str, **kw) -> RenderOptions:
    return RenderOptions(frames=6, rig="survey", size="64x40", views="defects:0.5", randomize=True,
                         classmap="builtin:road_defects_br", formats="mmseg", executor=executor, workers=2, seed=9,
                         **kw)


@pytest.fixture
def ray_cluster(request):
    """A local Ray cluster with ``request.param`` fake GPUs (shut down after the test)."""
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        ray.shutdown()
    ray.init(num_cpus=2, num_gpus=request.param, include_dashboard=False, log_to_driver=False,
             logging_level="ERROR")
    yield ray
    ray.shutdown()


@pytest.mark.parametrize("ray_cluster", [2], indirect=True)
@pytest.mark.parametrize("same_filesystem", [True, pytest.param(False, marks=pytest.mark.slow)],   # ~12 s each:
                         ids=["in-place", "bytes"])       # Ray's bytes against one process's, in the default run
def test_frames_are_spread_over_the_gpus_with_the_bytes_of_one_process(road, pm, tmp_path, ray_cluster,
                                                                       monkeypatch, same_filesystem):
    """The tasks share the driver's filesystem here; ``bytes``: the driver's token file never
    appears (as for a task on another node), so the files must travel as bytes."""
    monkeypatch.setattr(gpu_shards, "on_gpus", lambda device: True)    # the CPU stands in for the cards
    if not same_filesystem:
        monkeypatch.setattr(gpu_shards, "_write_token", lambda path, token: None)
    outs = {name: tmp_path / name for name in ("serial", "ray")}
    summaries = {name: run_render(road, outs[name], _options(name), pm=pm) for name in outs}

    shards = summaries["ray"]["shards"]
    assert [(s["first"], s["frames"]) for s in shards] == [(0, 3), (3, 3)]
    assert sorted(s["gpu"] for s in shards) == ["0", "1"]             # each task had its own card
    assert [s["processes"] for s in shards] == [1, 1]                # 2 CPUs over 2 GPUs, one left: at least 1
    assert [s["direct"] for s in shards] == [same_filesystem] * 2
    for s in shards:                     # when each card rendered its frames; which card (None: no CUDA here)
        t0, t1 = s["frames_from_to"]
        assert 0 < t1 - t0 < 600 and s["card"] is None
    per_frame = {p.stat().st_ino: p.stat().st_size for p in outs["serial"].rglob("*")    # links once
                 if p.is_file() and p.stem.isdigit()}                                  # 000000.png ...
    streamed = [s["streamed_bytes"] for s in shards]
    assert sum(streamed) == (0 if same_filesystem else sum(per_frame.values())), streamed
    assert "shards" not in summaries["serial"]

    files = assert_same_dataset(outs["serial"], outs["ray"])
    assert len([f for f in files if f.suffix in (".png", ".jpg")]) >= 12    # 6 frames: images and labels


@pytest.mark.slow
@pytest.mark.parametrize("ray_cluster", [2], indirect=True)
def test_an_error_while_tasks_write_in_place_leaves_nothing(road, pm, tmp_path, ray_cluster, monkeypatch):
    """The driver fails after frames were placed in its staging folder while the tasks still
    write there: the tasks are stopped before the folder goes, so nothing is left."""
    monkeypatch.setattr(gpu_shards, "on_gpus", lambda device: True)
    put_at = FrameSink.put_at

    def failing(sink, k, out):
        if k == 4:
            raise RoadtwinError("frame 4: disk full")
        put_at(sink, k, out)

    monkeypatch.setattr(FrameSink, "put_at", failing)
    with pytest.raises(RoadtwinError, match="frame 4: disk full"):
        run_render(road, tmp_path / "out/o", _options("ray"), pm=pm)
    time.sleep(1.0)                            # a task still writing would show by now
    assert not list((tmp_path / "out").iterdir())


@pytest.mark.slow
@pytest.mark.parametrize("ray_cluster", [0], indirect=True)
def test_gpu_device_on_a_cluster_without_gpus_is_one_line(road, pm, tmp_path, ray_cluster):
    with pytest.raises(RoadtwinError) as err:
        run_render(road, tmp_path / "o", _options("ray", device="cuda"), pm=pm)
    message = str(err.value)
    assert "\n" not in message and "--executor ray" in message and "--device cuda" in message, message
    assert "no GPU" in message
    assert not (tmp_path / "o").exists()


def test_split_shards_is_contiguous_and_covers_every_frame():
    assert gpu_shards.split_shards(7, 3) == [range(0, 2), range(2, 5), range(5, 7)]
    assert gpu_shards.split_shards(2, 8) == [range(0, 1), range(1, 2)]
    assert gpu_shards.split_shards(5, 1) == [range(0, 5)]


def _written_one_by_one(tmp_path) -> tuple[list, dict]:
    """Five frames (frame 2's image as JPEG bytes, written unchanged) written frame by frame with
    ``add`` into ``tmp_path/one``: the reference the other writing paths must equal."""
    frames = [_frame(i) for i in range(5)]
    jpeg = {2: b"\xff\xd8 not decoded \xff\xd9"}
    one = _writer(tmp_path / "one")
    for i, (f, rgb8) in enumerate(frames):
        one.add(f, rgb8, jpeg.get(i), record={"i": i})
    one.finish()
    return frames, jpeg


def test_frames_encoded_on_a_scratch_writer_are_the_files_the_writer_writes(tmp_path):
    """What the GPU tasks' processes do (``DatasetWriter.encode`` on a scratch folder of their
    own) and the driver then (``write_encoded``, ``commit``) gives the files, hard links and
    records of frame-by-frame ``add``; frame 2's image comes as JPEG bytes, written unchanged."""
    frames, jpeg = _written_one_by_one(tmp_path)
    many = _writer(tmp_path / "many")
    scratch = DatasetWriter(root=tmp_path / "scratch", **many.spec())
    encoded = [scratch.encode(i, f, rgb8, jpeg.get(i)) for i, (f, rgb8) in reversed(list(enumerate(frames)))]
    assert not [p for p in (tmp_path / "scratch").rglob("*") if p.is_file()]      # nothing left behind
    assert all(e.written.frame.depth is None for e in encoded)                   # arrays did not travel
    for e in reversed(encoded):
        many.commit(many.write_encoded(e), {"i": e.written.index})
    many.finish()
    assert _tree(tmp_path / "one") == _tree(tmp_path / "many")
    assert encoded[2].files["images/000002.jpg"] == jpeg[2]
    for stem in ("000000.png", "000002.jpg"):
        image, link = tmp_path / "many/images" / stem, tmp_path / "many/mmseg/img_dir/train" / stem
        assert image.stat().st_ino == link.stat().st_ino                         # a hard link, as add makes


def test_frames_placed_in_the_committing_writers_folder_are_the_files_the_writer_writes(tmp_path):
    """What the GPU tasks' processes do on the driver's filesystem (``DatasetWriter.place`` by
    a writer of their own on the driver's folder, in any order) and the driver then
    (``write_encoded``: nothing, ``commit``) gives the files, hard links and records of ``add``."""
    frames, jpeg = _written_one_by_one(tmp_path)
    many = _writer(tmp_path / "many")
    elsewhere = DatasetWriter(root=tmp_path / "many", **many.spec())
    placed = [elsewhere.place(i, f, rgb8, jpeg.get(i)) for i, (f, rgb8) in reversed(list(enumerate(frames)))]
    assert all(p.placed and not p.files and not p.links for p in placed)        # no bytes to carry
    assert all(p.written.frame.depth is None for p in placed)                    # nor arrays
    for p in reversed(placed):
        many.commit(many.write_encoded(p), {"i": p.written.index})
    many.finish()
    assert _tree(tmp_path / "one") == _tree(tmp_path / "many")
    image, link = tmp_path / "many/images/000002.jpg", tmp_path / "many/mmseg/img_dir/train/000002.jpg"
    assert image.read_bytes() == jpeg[2] and image.stat().st_ino == link.stat().st_ino
