"""``roadtwin render --events``: a continuous drive along one lane, its frames fed to the event
camera (on the renderer's device when it can simulate there, else by the core's simulator)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...errors import RoadtwinError
from ...render import Camera, EventSimulator, Intrinsics, lane_trajectory
from .options import MAX_FRAMES, RenderOptions, Rig, check_range, parse_size

__all__ = ["EventDrive", "check_events"]

Progress = Callable[[str, int, int], None]


def check_events(o: RenderOptions, r: Rig) -> "EventDrive | None":
    """--events' options checked; the drive to simulate, or None without --events."""
    ev_w, ev_h = parse_size(o.event_size, "--event-size") if o.event_size else (r.width, r.height_px)
    if not o.events:
        return None
    check_range("--event-frames", o.event_frames, 2, MAX_FRAMES)
    check_range("--event-threshold", o.event_threshold, 1e-6, 100.0)
    check_range("--speed", o.speed, 1e-3, 200.0, "m/s")
    check_range("--event-rate", o.event_rate, 1e-3, 1e6, "Hz")
    try:
        import h5py  # noqa: F401  (heavy, optional: only --events writes HDF5)
    except ImportError:
        raise RoadtwinError("--events writes HDF5 and needs h5py (pip install h5py)") from None
    return EventDrive((ev_w, ev_h), o.event_frames, o.event_threshold, o.speed, o.event_rate)


@dataclass
class EventDrive:
    """The drive: ``start`` renders its frames, ``write`` simulates and writes the events."""

    size: tuple[int, int]
    n_frames: int
    threshold: float
    speed: float
    rate_hz: float
    _run: tuple | None = None

    def start(self, rend, mesh, params, lanes, ground, seed: int, r: Rig) -> "EventDrive":
        prepared = rend.prepare(mesh, params)
        times, poses = lane_trajectory(lanes, np.random.default_rng([seed, 1]), ground, speed=self.speed,
                                       rate_hz=self.rate_hz, n_frames=self.n_frames, height=r.mount_height_m)
        cams = [Camera(Intrinsics.from_fov(*self.size, r.hfov_deg), p) for p in poses]
        frames = rend.render(prepared, cams, dataclasses.replace(params, shade=True))
        self._run = (rend, prepared, cams, times, poses, params, seed, frames)
        return self

    def write(self, writer, progress: Progress | None) -> int:
        """Simulate the events and write them; their count."""
        report = progress or (lambda *_: None)
        rend, prepared, cams, times, poses, params, seed, frames = self._run
        got = rend.render_events(prepared, cams, times, params, progress=lambda k, n: report("events", k, n),
                                 threshold=self.threshold, seed=seed)
        if got is None:
            sim = EventSimulator(*self.size, threshold=self.threshold, seed=seed)
            parts = []
            for k, (frame, t) in enumerate(zip(frames, times)):
                parts.append(sim.step(frame.rgb, float(t)))
                report("events", k + 1, len(times))
            got = {key: np.concatenate([c[key] for c in parts]) for key in ("x", "y", "t", "p")}, sim.params()
        ev, sim_params = got
        writer.write_events(ev, times, poses, self.size, {**sim_params, "speed_mps": self.speed, "rate_hz": self.rate_hz})
        return len(ev["t"])
