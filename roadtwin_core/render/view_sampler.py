"""Camera views built for training data: a target share of frames with a pothole or crack in
view, the rest at random along the lanes, each with per-frame rig jitter. numpy only.

Why not plain random poses: on a real survey road defects are sparse, so uniformly placed
cameras mostly see bare asphalt (the issue's six random views had 0-146 defect pixels of
518,400). A network learns defects from frames that contain them, and learns not to invent
them from frames that do not: the sampler controls that mix.

Pieces:

* :func:`~roadtwin_core.render.lane_chains.chain_lanes` joins the per-segment lane centrelines of a town (a layout cuts a road
  every 25 m) into continuous lanes, so a camera 20 m before a segment border sees past it and a
  lane's arc length runs the whole road.
* :func:`defect_targets` reads defect positions and types from a composed town
  (``roadtwin:defect:poseXYYaw``).
* :func:`sample_views` draws the poses. Frame ``i`` depends only on ``(seed, i)`` and the scene
  (its own generator ``default_rng([seed, i])``; whether it targets a defect follows an even
  spread of the share over the indices), so a sharded render draws the same frames.

A defect is *in view* when, in plan, it lies ``near..far`` m ahead along the camera's heading
and within half the horizontal field of view of it (:func:`in_view`). The camera sits on the
vehicle: its height is above the road under the wheels and its pitch and roll follow the road's
grade and crossfall (a car on a 2 % crown leans 1.1 degrees), plus the rig's jitter. A pose
on or just behind a vehicle standing in the lane (a town's props placed ``lane``:
:func:`~roadtwin_core.render.cameras.lane_keep_out`) is redrawn.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np

from ..errors import RoadtwinError
from .cameras import NO_KEEP_OUT, Camera, GroundFn, Intrinsics, KeepOut, Lane, lane_keep_out, look_from
from .lane_chains import ChainedLane, chain_lanes, lane_ahead, project_to_lane, unit_vector  # noqa: F401  (re-exported)
from .scene import stage_lanes
from .view_draws import TRACK_HALF_M, WHEELBASE_HALF_M, clear_of, lane_spots, road_attitudes

TARGET_TYPES = ("pothole", "crack")
DEFECT_DISTANCE_M = (5.0, 25.0)                # an aimed defect's distance ahead of the camera, by default
DEAD_END_MARGIN_M = 25.0                       # background views keep this far back from a road's end


@dataclass(frozen=True)
class ViewRig:
    """Where the camera sits on the vehicle and what it sees (a named preset converts to this)."""

    mount_height_m: float = 2.4
    pitch_deg: float = -12.0
    hfov_deg: float = 60.0
    width_px: int = 512
    height_px: int = 320
    roll_deg: float = 0.0

    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_fov(self.width_px, self.height_px, self.hfov_deg)

    def check(self) -> "ViewRig":
        if not (math.isfinite(self.mount_height_m) and self.mount_height_m > 0):
            raise RoadtwinError(f"rig: mount height must be > 0 m, got {self.mount_height_m}")
        if not -89.0 <= self.pitch_deg <= 89.0:
            raise RoadtwinError(f"rig: pitch must be within +-89 degrees, got {self.pitch_deg}")
        self.intrinsics()   # checks size and field of view
        return self


@dataclass(frozen=True)
class Jitter:
    """Half-widths of the uniform per-frame perturbations (a real rig bounces and drivers wander)."""

    height_m: float = 0.15
    pitch_deg: float = 2.0
    roll_deg: float = 1.0
    lateral_m: float = 0.4
    yaw_deg: float = 1.5

    def check(self) -> "Jitter":
        for k, v in asdict(self).items():
            if not (math.isfinite(v) and v >= 0):
                raise RoadtwinError(f"view jitter {k} must be a finite number >= 0, got {v}")
        return self


@dataclass
class DefectTargets:
    """Defect ids, types and plan positions (N,2) of a town."""

    ids: list[str]
    types: list[str]
    xy: np.ndarray

    def __post_init__(self) -> None:
        self.xy = np.asarray(self.xy, dtype=np.float64).reshape(-1, 2)
        if not (len(self.ids) == len(self.types) == len(self.xy)):
            raise RoadtwinError("defect targets: ids, types and positions differ in length")


@dataclass
class View:
    """One sampled camera: pose, where it is on which lane, what it was aimed at, and the
    jitter drawn for it (so a dataset's meta.json can say exactly how the frame was made)."""

    index: int
    camera: Camera
    lane_id: str
    segment_id: str
    s_m: float
    target: str | None                  # defect id the frame was aimed at (None: random frame)
    in_view: tuple[str, ...]            # target-type defects in view (see in_view())
    jitter: dict[str, float]

    @property
    def cam_to_world(self) -> np.ndarray:
        return self.camera.cam_to_world

    def as_dict(self) -> dict:
        return {"index": self.index, "lane": self.lane_id, "segment": self.segment_id, "s_m": round(self.s_m, 4),
                "target": self.target, "in_view": list(self.in_view), "jitter": self.jitter,
                "cam_to_world": self.camera.cam_to_world.tolist()}


# ------------------------------------------------------------------------------ lanes

# ------------------------------------------------------------------------------ defects
def defect_targets(town) -> DefectTargets:
    """Ids, types and plan positions of a composed town's defects (a ``TownScene`` from
    ``roadtwin_core.usd.town_reader.load_town``)."""
    ids, types, xy = [], [], []
    for d in town.defects:
        pose = d.attributes.get("poseXYYaw")
        if pose is None or len(pose) < 2:
            raise RoadtwinError(f"{getattr(town, 'source', 'town')}: defect {d.id} has no roadtwin:defect:poseXYYaw")
        ids.append(d.id)
        types.append(d.defect_type)
        xy.append((float(pose[0]), float(pose[1])))
    return DefectTargets(ids, types, np.array(xy).reshape(-1, 2))


def in_view(cam_to_world: np.ndarray, xy: np.ndarray, hfov_deg: float, near_m: float = DEFECT_DISTANCE_M[0],
            far_m: float = DEFECT_DISTANCE_M[1]) -> np.ndarray:
    """Which plan points lie ``near..far`` m ahead along the camera's heading and within half
    the horizontal field of view of it (a plan-view test: roll and pitch are a few degrees)."""
    xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
    if not len(xy):
        return np.zeros(0, dtype=bool)
    f = cam_to_world[:3, 2]
    h = unit_vector(np.array([f[0], f[1]]))
    d = xy - cam_to_world[:2, 3]
    ahead = d @ h
    side = d @ np.array([-h[1], h[0]])
    bearing = np.abs(np.arctan2(side, ahead))
    return (ahead >= near_m) & (ahead <= far_m) & (bearing <= math.radians(hfov_deg) / 2)


# ------------------------------------------------------------------------------ sampling
def road_attitude(ground: GroundFn, xy: np.ndarray, heading: float) -> tuple[float, float, float]:
    """Road height under the vehicle and the grade pitch / crossfall roll (radians) it puts on
    a body-mounted camera; a missing side counts as level (one vehicle of ``road_attitudes``)."""
    z, pitch, roll = road_attitudes(ground, np.asarray(xy, dtype=np.float64)[None], np.array([float(heading)]))
    return float(z[0]), pitch[0], roll[0]


def _is_targeted(i: int, share: float) -> bool:
    """Spread ``share`` evenly over frame indices: every prefix of n frames has round-down
    ``share * n`` (or one more) targeted frames, and frame i's role depends on i alone."""
    return math.floor((i + 1) * share + 1e-9) > math.floor(i * share + 1e-9)


def sample_views(lanes: Sequence[Lane], defects: DefectTargets, ground: GroundFn, n: int, *, rig: ViewRig = ViewRig(),
                 share: float = 0.7, seed: int = 0, jitter: Jitter = Jitter(), near_m: float = DEFECT_DISTANCE_M[0], far_m: float = DEFECT_DISTANCE_M[1],
                 target_types: Sequence[str] = TARGET_TYPES, max_lateral_m: float = 8.0, background: str = "uniform",
                 start: int = 0, max_tries: int = 60, keep_out: KeepOut = NO_KEEP_OUT) -> list[View]:
    """Frames ``start .. start + n - 1``: a ``share`` of them aimed at a random pothole or crack
    (``target_types``) placed ``near..far`` m ahead inside the field of view, the rest uniform
    along the lanes, short of the last ``DEAD_END_MARGIN_M`` of a lane with no road ahead
    (:func:`dead_end_margins`) (``background="uniform"``; ``"clear"`` redraws them until no target-type
    defect is in view, falling back to the last draw after ``max_tries``). Targets are defects
    within ``max_lateral_m`` of a lane centreline (own lane, the opposing one, the shoulders);
    each is seen from every lane it lies near, in that lane's travel direction. No camera stands
    inside ``keep_out`` (vehicles stopped in the lanes)."""
    _check_view_options(rig, jitter, n, share, near_m, far_m, background, seed)
    lanes = [l for l in lanes if l.length > 2 * WHEELBASE_HALF_M]
    if not lanes:
        raise RoadtwinError("no lane centreline to place cameras on")
    intr = rig.intrinsics()
    targets = _Targets.on(lanes, defects, target_types, near_m, max_lateral_m)
    if share > 0 and n > 0 and not len(targets.defect):
        raise RoadtwinError(f"no {' or '.join(target_types)} lies within {max_lateral_m} m of a lane: "
                            f"cannot aim {share:.0%} of the views at defects")
    drawer = _ViewDrawer(lanes, targets, ground, rig, jitter, near_m, far_m, background, max_tries, keep_out)
    frames = [_Frame(i, np.random.default_rng([seed, i]), share > 0 and _is_targeted(i, share))
              for i in range(start, start + n)]
    drawer.choose(frames)
    views = []
    for frame in frames:
        i = frame.index
        m, j, lane_i, s, target, seen = frame.chosen
        lane = lanes[lane_i]
        seg = lane.segment_at(s) if isinstance(lane, ChainedLane) and lane.segments else lane.id
        views.append(View(i, Camera(intr, m), lane.id, seg, s, target,
                          tuple(targets.ids[k] for k in np.nonzero(seen)[0]), j))
    return views


def _check_view_options(rig: ViewRig, jitter: Jitter, n: int, share: float, near_m: float, far_m: float,
                        background: str, seed: int) -> None:
    rig.check()
    jitter.check()
    if n < 0:
        raise RoadtwinError(f"number of views must be >= 0, got {n}")
    if not 0.0 <= share <= 1.0:
        raise RoadtwinError(f"share of views with defects must be in [0, 1], got {share}")
    if not 0 <= near_m < far_m:
        raise RoadtwinError(f"defect distance range must satisfy 0 <= near < far, got {near_m}..{far_m}")
    if background not in ("uniform", "clear"):
        raise RoadtwinError(f"background views must be 'uniform' or 'clear', got {background!r}")
    if seed < 0:
        raise RoadtwinError(f"seed must be >= 0, got {seed}")


@dataclass
class _Targets:
    """The target-type defects (positions, ids) and every (defect, lane) pair a targeted frame
    can use: ``defect`` (index into ``xy``), ``lane`` and ``s``, the defect's arc length on it."""

    xy: np.ndarray
    ids: list[str]
    defect: np.ndarray
    lane: np.ndarray
    s: np.ndarray

    @classmethod
    def on(cls, lanes: Sequence[Lane], defects: DefectTargets, target_types: Sequence[str], near_m: float,
           max_lateral_m: float) -> _Targets:
        is_target = (np.isin(np.asarray(defects.types, dtype=object), list(target_types)) if len(defects.ids)
                     else np.zeros(0, bool))
        target_xy = defects.xy[is_target]
        target_ids = [i for i, t in zip(defects.ids, is_target) if t]
        cand_defect, cand_lane, cand_s = [], [], []
        for li, lane in enumerate(lanes):
            if not len(target_xy):
                break
            s, lat = project_to_lane(lane, target_xy)
            ok = (np.abs(lat) <= max_lateral_m) & (s > near_m + 1.0)
            cand_defect.append(np.nonzero(ok)[0])
            cand_lane.append(np.full(int(ok.sum()), li))
            cand_s.append(s[ok])
        return cls(target_xy, target_ids,
                   np.concatenate(cand_defect) if cand_defect else np.zeros(0, int),
                   np.concatenate(cand_lane) if cand_lane else np.zeros(0, int),
                   np.concatenate(cand_s) if cand_s else np.zeros(0))


@dataclass
class _Frame:
    """One frame's draws so far: its generator (``default_rng([seed, index])``), its role and
    the last pose that passed (``_ViewDrawer.choose``'s tuple), ``done`` once its role is met."""

    index: int
    rng: np.random.Generator
    aimed: bool
    chosen: tuple | None = None
    done: bool = False


def dead_end_margins(lanes: Sequence[Lane], margin_m: float = DEAD_END_MARGIN_M, join_m: float = 25.0,
                     max_turn_deg: float = 135.0) -> np.ndarray:
    """Per lane, the last metres a background view keeps off: ``margin_m`` where the lane ends
    with no road ahead (no other lane starts within ``join_m`` of its end, turning less than
    ``max_turn_deg``: a highway's end, where the opposite lane starts heading back), else 0 (a
    junction). A survey camera there would look past the road's end into the verge. Never more
    than leaves a metre to draw from."""
    starts = np.array([l.points[0] for l in lanes])
    start_heading = np.array([float(l.heading(np.array([min(1.0, l.length / 2)]))[0]) for l in lanes])
    out = np.zeros(len(lanes))
    for i, lane in enumerate(lanes):
        end = lane.points[-1]
        h = float(lane.heading(np.array([max(lane.length - 1.0, lane.length / 2)]))[0])
        turn = np.degrees(np.abs((start_heading - h + math.pi) % (2 * math.pi) - math.pi))
        near = (np.linalg.norm(starts - end, axis=1) < join_m) & (turn < max_turn_deg)
        near[i] = False
        if not near.any():
            out[i] = min(margin_m, max(0.0, lane.length - 2 * WHEELBASE_HALF_M - 1.0))
    return out


@dataclass
class _ViewDrawer:
    """The frames' random draws, in a fixed order per frame's rng: the spot (lane and arc length),
    the jittered camera there, and what it sees; redrawn until the frame's role is met. Frames
    draw in rounds, one try each, so that the geometry of a round's tries is computed together
    (``view_draws``); a frame's own draws, and so its view, are those of trying it alone."""

    lanes: list[Lane]
    targets: _Targets
    ground: GroundFn
    rig: ViewRig
    jitter: Jitter
    near_m: float
    far_m: float
    background: str
    max_tries: int
    keep_out: KeepOut = NO_KEEP_OUT

    def __post_init__(self):
        self.lengths = np.array([l.length for l in self.lanes])
        self.lane_p = self.lengths / self.lengths.sum()
        self.end_margin = dead_end_margins(self.lanes)

    def choose(self, frames: list[_Frame]) -> None:
        """Sets each frame's ``chosen``: (cam_to_world, jitter, lane index, s, target id or None, seen mask)."""
        active = list(frames)
        for _ in range(self.max_tries):
            if not active:
                break
            self._try([spot for spot in (self._spot(f) for f in active) if spot is not None])
            active = [f for f in active if not f.done]
        failed = next((f for f in frames if f.chosen is None), None)
        if failed is not None:
            what = ("aim a view at a defect" if failed.aimed else
                    "place a view on a lane (the road is missing under them, or vehicles stand there)")
            raise RoadtwinError(f"view {failed.index}: could not {what} in {self.max_tries} tries")

    def _spot(self, f: _Frame) -> tuple | None:
        """A try's first draws: (frame, lane index, s, lateral offset, candidate); None when an
        aimed spot falls before the lane's start (the try is spent)."""
        t, rng = self.targets, f.rng
        c = -1
        if f.aimed:
            c = int(rng.integers(len(t.defect)))
            lane_i = int(t.lane[c])
            s = float(t.s[c]) - rng.uniform(self.near_m + 0.5, self.far_m - 0.5)
            if s < WHEELBASE_HALF_M:
                return None
        else:
            lane_i = int(rng.choice(len(self.lanes), p=self.lane_p))
            s = float(rng.uniform(WHEELBASE_HALF_M, self.lanes[lane_i].length - WHEELBASE_HALF_M - self.end_margin[lane_i]))
        return f, lane_i, s, rng.uniform(-self.jitter.lateral_m, self.jitter.lateral_m), c

    def _try(self, spots: list[tuple]) -> None:
        """One try of each spot's frame: the camera there (none where a vehicle stands or there is
        no road), what it sees, and whether the frame's role is met."""
        if not spots:
            return
        t = self.targets
        heading, xy = lane_spots(self.lanes, np.array([sp[1] for sp in spots]), np.array([sp[2] for sp in spots]),
                                 np.array([sp[3] for sp in spots]))
        free = np.nonzero(clear_of(self.keep_out, xy))[0]
        z, road_pitch, road_roll = road_attitudes(self.ground, xy[free], heading[free])
        for k, zk, pk, rk in zip(free.tolist(), z.tolist(), road_pitch, road_roll):
            if not math.isfinite(zk):
                continue
            f, lane_i, s, lat, c = spots[k]
            m, j = self.camera(f.rng, xy[k], float(heading[k]), lat, (zk, pk, rk))
            seen = in_view(m, t.xy, self.rig.hfov_deg, self.near_m, self.far_m) if len(t.xy) else np.zeros(0, bool)
            if f.aimed and not seen[t.defect[c]]:
                continue
            f.chosen = (m, j, lane_i, s, t.ids[t.defect[c]] if f.aimed else None, seen)
            f.done = f.aimed or self.background == "uniform" or not seen.any()

    def camera(self, rng, xy: np.ndarray, heading: float, lat: float, road: tuple) -> tuple[np.ndarray, dict]:
        """The rig jittered on the road at ``xy`` (``road``: height, pitch and roll there)."""
        jitter, rig = self.jitter, self.rig
        z, road_pitch, road_roll = road
        j = {"height_m": rng.uniform(-jitter.height_m, jitter.height_m),
             "pitch_deg": rng.uniform(-jitter.pitch_deg, jitter.pitch_deg),
             "roll_deg": rng.uniform(-jitter.roll_deg, jitter.roll_deg),
             "lateral_m": lat, "yaw_deg": rng.uniform(-jitter.yaw_deg, jitter.yaw_deg)}
        yaw = heading + math.radians(j["yaw_deg"])
        pitch = math.radians(rig.pitch_deg + j["pitch_deg"]) + road_pitch
        roll = math.radians(rig.roll_deg + j["roll_deg"]) + road_roll
        m = look_from((xy[0], xy[1], z + rig.mount_height_m + j["height_m"]), yaw, pitch, roll)
        return m, {k: round(float(v), 6) for k, v in j.items()}


def stage_views(stage_path, town, ground: GroundFn, n: int, **options) -> tuple[list[View], list[ChainedLane]]:
    """What ``roadtwin render --views defects:SHARE`` does: the stage's driving lanes chained,
    its defects as targets, then :func:`sample_views` (``options`` are passed on). Returns the
    views and the chained lanes (the ego-lane labeller takes ``lane_ahead`` of a view's lane)."""
    lanes = chain_lanes(stage_lanes(stage_path))
    if not lanes:
        raise RoadtwinError(f"{stage_path}: no driving lane centrelines (roadtwin:segment:centerline) to place views on")
    options.setdefault("keep_out", lane_keep_out(town))
    return sample_views(lanes, defect_targets(town), ground, n, **options), lanes


def share_with_targets(views: Sequence[View]) -> float:
    """Fraction of views with at least one target-type defect in view."""
    return float(np.mean([bool(v.in_view) for v in views])) if views else 0.0
