"""The warp event camera (``roadtwin_warp_render.event_kernels``, what runs where CUDA frames
are) against the numpy reference (``roadtwin_core.render.events``), run here on warp's CPU
device: the same events (pixel, polarity, order; times to float64 rounding) frame after frame,
with thresholds per pixel, several crossings per step and the refractory rule all in play."""
import math

import numpy as np
import pytest

from roadtwin_core.render import EventSimulator

wp = pytest.importorskip("warp")
from roadtwin_warp_render.event_kernels import WarpEventSimulator  # noqa: E402


def frames(h, w, n, seed):
    """A drifting bright bar over a textured background with flicker: ON and OFF edges, pixels
    that cross several thresholds in one step, others that stay still."""
    rng = np.random.default_rng(seed)
    tex = rng.uniform(0.05, 1.0, (h, w, 3))
    xs = np.arange(w)[None, :]
    out = []
    for k in range(n):
        bar = (np.abs(xs - (2 + 1.7 * k)) < 2.5)[..., None]
        flick = 1.0 + 0.5 * math.sin(k) * (rng.random((h, w, 1)) < 0.2)
        out.append((tex * flick * np.where(bar, 6.0, 1.0)).astype(np.float32))
    return out


@pytest.mark.parametrize("refractory_s", [0.0, 1e-4, 3e-3])
def test_warp_events_match_numpy_reference(refractory_s):
    h, w = 12, 17
    ref = EventSimulator(w, h, threshold=0.15, sigma=0.03, refractory_s=refractory_s, seed=3)
    gpu = WarpEventSimulator(w, h, threshold=0.15, sigma=0.03, refractory_s=refractory_s, seed=3, device="cpu")
    total = multi = 0
    for k, fr in enumerate(frames(h, w, 9, seed=5)):
        t = 0.004 * k + 0.001 * (k % 2)
        a, b = ref.step(fr, t), gpu.step(fr, t)
        assert len(a["t"]) == len(b["t"]), k
        for key in ("x", "y", "p"):
            np.testing.assert_array_equal(a[key], b[key], err_msg=f"frame {k} {key}")
            assert a[key].dtype == b[key].dtype
        np.testing.assert_allclose(a["t"], b["t"], rtol=0, atol=1e-12)
        total += len(a["t"])
        if len(a["t"]):
            _, c = np.unique(a["y"].astype(int) * w + a["x"], return_counts=True)
            multi += int((c > 1).sum())
    assert total > 300 and multi > 10       # the comparison exercised repeated crossings


def test_warp_events_closed_form_and_device_frames():
    """A log ramp of 0.7 over 10 ms with thresholds 0.2 (no noise): 3 ON events per pixel at
    2/7, 4/7, 6/7 of the step; frames given as warp arrays (as the renderer keeps them) and
    as single-channel luminance."""
    sim = WarpEventSimulator(3, 2, threshold=0.2, sigma=0.0, refractory_s=0.0, eps=1e-9, device="cpu")
    img = np.full((2, 3), 0.1, dtype=np.float32)
    sim.reset(wp.array(img, dtype=wp.float32, device="cpu"), 0.0)
    ev, count = sim.step_device(wp.array(img * math.exp(0.7), dtype=wp.float32, device="cpu"), 0.01)
    assert count == 18
    t = ev["t"].numpy()
    assert (ev["p"].numpy() == 1).all() and np.all(np.diff(t) >= 0)
    np.testing.assert_allclose(np.unique(t), [0.01 * 0.2 / 0.7, 0.01 * 0.4 / 0.7, 0.01 * 0.6 / 0.7], rtol=1e-5)
    with pytest.raises(ValueError, match="must increase"):
        sim.step(img, 0.01)
    with pytest.raises(ValueError, match="event camera is 3x2"):
        sim.step(np.zeros((3, 3), np.float32), 0.02)


def test_renderer_events_where_the_frames_are_match_reference_on_rendered_frames():
    """``WarpRenderer.render_events`` (what ``roadtwin render --events`` uses on CUDA: each view
    shaded and read by the event camera in device memory) against the numpy reference on the
    same renderer's frames, run here on warp's CPU device; on CPU it defers (returns None)."""
    import roadtwin_warp_render
    from roadtwin_core.render import Camera, Intrinsics, RenderParams, build_render_mesh, look_from
    from roadtwin_core.usd.town_reader import TownMesh, TownScene

    s = TownScene("Test", "test")
    x, y = np.meshgrid(np.linspace(-20, 20, 41), np.linspace(-20, 20, 41))   # a corrugated road: shading edges
    v = np.column_stack([x.ravel(), y.ravel(), 0.3 * np.sin(1.3 * x.ravel()) + 0.2 * np.cos(y.ravel())])
    i, j = np.meshgrid(np.arange(40), np.arange(40))
    a = (j * 41 + i).ravel()
    f = np.concatenate([np.column_stack([a, a + 1, a + 42]), np.column_stack([a, a + 42, a + 41])])
    s.roads = [TownMesh("/Test/Roads/seg0", "driving", v, f)]
    town = build_render_mesh(s)
    intr = Intrinsics.from_fov(24, 16, 70.0)
    cams = [Camera(intr, look_from((0.4 * k, 0.1 * k, 1.5), 0.2, math.radians(-35))) for k in range(5)]
    times = 0.002 * np.arange(5)
    params = RenderParams(shadows=False, device="cpu", backend="warp")
    rend = roadtwin_warp_render.WarpRenderer()
    assert rend.render_events(town, cams, times, params, seed=2) is None
    got, sim_params = rend.render_events(town, cams, times, params, any_device=True, seed=2, threshold=0.1)
    ref = EventSimulator(24, 16, seed=2, threshold=0.1)
    want = [ref.step(fr.rgb, float(t)) for fr, t in zip(rend.render(town, cams, params.__class__(
        **{**params.__dict__, "shade": True})), times)]
    want = {k: np.concatenate([w[k] for w in want]) for k in ("x", "y", "t", "p")}
    assert len(want["t"]) > 50 and sim_params == ref.params()
    for k in ("x", "y", "p"):
        np.testing.assert_array_equal(got[k], want[k])
    np.testing.assert_allclose(got["t"], want["t"], rtol=0, atol=1e-12)
