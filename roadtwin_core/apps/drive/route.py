"""Where the vehicle drives: a route (a world XY polyline the CG follows) and the speed along it.

Routes: ``auto`` (lanes of the stage chained end to start through junctions, the stretch of
``length`` m whose wheel tracks meet the most defects, clear of the vehicles standing in the
lanes: :mod:`.obstacles`), ``lane:ID[,ID...]`` (those lanes
chained in the order given) or a poses file (text rows ``x y``, ``x y z`` or TUM
``t x y z qx qy qz qw``; or a JSON list of ``[x, y]``). Every route is checked against the
road's collision mesh: both wheel tracks must stay on it, else one line naming where it leaves;
and against what stands in the lanes: one line naming the instance it runs into.

Speed: one speed (``--speed`` km/h), or a sweep's ``recommendations.json`` (``--speed-profile``):
cruise at ``--speed`` and cross each defect of the route at the speed the sweep recommended for
it (from ``slow_before_m`` before the defect to ``slow_after_m`` after it). The profile must be
for the vehicle driven (its ``vehicle`` field), else one line.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import RoadtwinError
from .obstacles import blocked_spans, free_stretches

MIN_AUTO_M = 10.0      # shortest stretch --route auto drives between vehicles standing in a lane

__all__ = ["Route", "SpeedProfile", "build_route", "check_on_road", "constant_speed", "load_speed_profile",
           "read_recommendations", "speed_profile", "wheel_hits"]


@dataclass
class Route:
    xy: np.ndarray                    # (K, 2) polyline the CG follows
    source: str                       # how it was made ("auto: lanes a > b", "file ...")
    lanes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        p = np.asarray(self.xy, dtype=np.float64).reshape(-1, 2)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-6])
        self.xy = p[keep]
        if len(self.xy) < 2:
            raise RoadtwinError(f"route ({self.source}): needs at least two distinct points")
        self.cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.xy, axis=0), axis=1))])

    @property
    def length(self) -> float:
        return float(self.cum[-1])

    def at(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Points and unit tangents at arclengths ``s`` (clamped)."""
        s = np.clip(np.atleast_1d(np.asarray(s, dtype=np.float64)), 0.0, self.length)
        k = np.clip(np.searchsorted(self.cum, s, side="right") - 1, 0, len(self.xy) - 2)
        seg = self.xy[k + 1] - self.xy[k]
        L = np.maximum(self.cum[k + 1] - self.cum[k], 1e-12)
        u = (s - self.cum[k]) / L
        return self.xy[k] + seg * u[:, None], seg / L[:, None]

    def project(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(arclength, signed left offset) of each point's nearest point on the route."""
        pts = np.atleast_2d(pts)
        a, b = self.xy[:-1], self.xy[1:]
        ab = b - a
        L2 = np.maximum((ab ** 2).sum(1), 1e-12)
        u = np.clip(((pts[:, None, :] - a) * ab).sum(-1) / L2, 0, 1)
        q = a + ab * u[..., None]
        d = np.linalg.norm(q - pts[:, None, :], axis=-1)
        k = d.argmin(1)
        i = np.arange(len(pts))
        s = self.cum[k] + u[i, k] * np.sqrt(L2[k])
        t = ab[k] / np.sqrt(L2[k])[:, None]
        r = pts - q[i, k]
        return s, t[:, 0] * r[:, 1] - t[:, 1] * r[:, 0]

    def crop(self, s0: float, s1: float) -> "Route":
        inner = (self.cum > s0) & (self.cum < s1)
        pts = np.vstack([self.at(s0)[0], self.xy[inner], self.at(s1)[0]])
        return Route(pts, self.source, self.lanes)


# ------------------------------------------------------------------------------------ lanes
def _chains(lanes, max_gap_m: float = 15.0, max_turn_deg: float = 30.0) -> list[list]:
    """Lanes chained end to start: the successor of a lane is the one whose start is nearest its
    end (within ``max_gap_m``, heading change under ``max_turn_deg``), straight on through a
    junction. Every lane with no predecessor starts a chain."""
    succ, has_pred = {}, set()
    for a in lanes:
        end, h_end = a.points[-1], a.heading(np.array([a.length - 1.0]))[0]
        best = None
        for b in lanes:
            if b is a:
                continue
            gap = float(np.linalg.norm(b.points[0] - end))
            turn = abs((b.heading(np.array([1.0]))[0] - h_end + math.pi) % (2 * math.pi) - math.pi)
            if gap <= max_gap_m and math.degrees(turn) <= max_turn_deg and (best is None or gap < best[0]):
                best = (gap, b)
        if best is not None:
            succ[a.id] = best[1]
            has_pred.add(best[1].id)
    chains = []
    for start in lanes:
        if start.id in has_pred:
            continue
        chain, seen, cur = [start], {start.id}, start
        while cur.id in succ and succ[cur.id].id not in seen:
            cur = succ[cur.id]
            chain.append(cur)
            seen.add(cur.id)
        chains.append(chain)
    return chains


def _chain_route(chain, source: str) -> Route:
    return Route(np.vstack([l.points for l in chain]), source, [l.id for l in chain])


def wheel_hits(route: Route, defects: list[dict], half_track_m: float, tire_half_width_m: float) -> list[dict]:
    """Defects whose footprint one of the wheel tracks (+-``half_track_m``) crosses: each with
    its arclength ``s`` along the route."""
    if not defects:
        return []
    c = np.array([d["xy"] for d in defects])
    s, off = route.project(c)
    out = []
    for d, si, oi in zip(defects, s, off):
        reach = d["half_width_m"] + tire_half_width_m
        if 0.5 < si < route.length - 0.5 and min(abs(oi - half_track_m), abs(oi + half_track_m)) <= reach:
            out.append({**d, "s": float(si), "offset_m": float(oi)})
    return out


def build_route(spec: str, stage_lanes, defects: list[dict], length_m: float | None, half_track_m: float,
                tire_half_width_m: float, obstacles: list | None = None, body_m: tuple[float, float] = (1.8, 4.5)
                ) -> Route:
    """``auto``, ``lane:ID,...`` or a poses file path (see the module doc). ``obstacles``: what
    stands in the lanes (:mod:`.obstacles`), which ``auto`` keeps clear of with a body of
    ``body_m`` (width, length); other routes are checked by the caller."""
    spec = str(spec).strip()
    if spec == "auto" or spec.startswith("lane:"):
        lanes = list(stage_lanes)
        if not lanes:
            raise RoadtwinError("route: the stage has no driving lanes (roadtwin:segment:centerline)")
        if spec == "auto":
            return _auto_route(lanes, defects, length_m, half_track_m, tire_half_width_m, obstacles or [], body_m)
        ids = [x.strip() for x in spec[5:].split(",") if x.strip()]
        by_id = {l.id: l for l in lanes}
        missing = [i for i in ids if i not in by_id]
        if not ids or missing:
            raise RoadtwinError(f"route {spec!r}: no lane {missing[0] if missing else '(none given)'!r} in the stage "
                                f"(e.g. {', '.join(sorted(by_id)[:4])})")
        r = _chain_route([by_id[i] for i in ids], f"lanes {' > '.join(ids)}")
        return r.crop(0.0, min(length_m, r.length)) if length_m else r
    path = Path(spec)
    if not path.is_file():
        raise RoadtwinError(f"route {spec!r}: not auto, lane:ID[,ID...] or an existing poses file")
    xy = _read_route_file(path)
    r = Route(xy, f"file {path.name}")
    return r.crop(0.0, min(length_m, r.length)) if length_m else r


def _auto_route(lanes, defects, length_m, half_track_m, tire_half_width_m, obstacles, body_m) -> Route:
    """The stretch of ``length_m`` (or less where the chain is shorter or a vehicle stands in the
    lane) whose wheel tracks meet the most defects; stretches cut short by standing vehicles
    only where no chain has a clear one."""
    best = None
    for chain in _chains(lanes):
        r = _chain_route(chain, "auto")
        full = min(length_m or r.length, r.length)
        hits = wheel_hits(r, defects, half_track_m, tire_half_width_m)
        for a, b in free_stretches(r.length, blocked_spans(r, obstacles, *body_m)):
            window = min(full, b - a)
            if window < min(full, MIN_AUTO_M):     # a stretch cut short between standing vehicles
                continue
            # the window of `window` m with the most defects in the wheel tracks
            for s0 in [a] + [h["s"] - 15.0 for h in hits]:
                s0 = min(max(s0, a), b - window)
                n = sum(s0 + 5.0 <= h["s"] <= s0 + window - 5.0 for h in hits)
                key = (window >= full, n, window, -s0)
                if best is None or key > best[0]:
                    best = (key, r, s0, window)
    if best is None:
        raise RoadtwinError(f"route auto: vehicles stand in every lane at least every {MIN_AUTO_M:g} m "
                            f"({len(obstacles)} standing instances): give lanes or a poses file")
    (clear, *_), r, s0, window = best
    r = r.crop(s0, s0 + window)
    r.source = f"auto: lanes {' > '.join(r.lanes)} from s = {s0:.1f} m" + (
        "" if clear else f" ({window:.0f} m: vehicles stand in the lanes)")
    return r


def _read_route_file(path: Path) -> np.ndarray:
    text = path.read_text(encoding="utf-8", errors="replace")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(text)
            data = data.get("poses", data) if isinstance(data, dict) else data
            a = np.array([p["position"][:2] if isinstance(p, dict) else p[:2] for p in data], dtype=np.float64)
        else:
            rows = [ln.replace(",", " ").split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
            a = np.array([[float(v) for v in r] for r in rows], dtype=np.float64)
            if a.ndim != 2 or a.shape[1] not in (2, 3, 8):
                raise ValueError(f"rows of 2, 3 or 8 numbers expected, got {a.shape[1] if a.ndim == 2 else '?'}")
            a = a[:, 1:3] if a.shape[1] == 8 else a[:, :2]
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise RoadtwinError(f"route file {path}: cannot read ({str(exc).splitlines()[0]})") from None
    if len(a) < 2 or not np.isfinite(a).all():
        raise RoadtwinError(f"route file {path}: needs at least two finite points")
    return a


def check_on_road(route: Route, occupancy, half_track_m: float, tire_half_width_m: float, step_m: float = 0.25) -> None:
    """Both wheel tracks (their outer tire edges) stay on the road mesh along the whole route."""
    s = np.arange(0.0, route.length + step_m / 2, step_m)
    p, t = route.at(s)
    n = np.column_stack([-t[:, 1], t[:, 0]])
    for lat in (-half_track_m - tire_half_width_m, 0.0, half_track_m + tire_half_width_m):
        ok = occupancy.covered(p + n * lat)
        if not ok.all():
            k = int(np.argmin(ok))
            x, y = p[k] + n[k] * lat
            raise RoadtwinError(f"route ({route.source}) leaves the road at s = {s[k]:.1f} m "
                                f"(wheel track at x = {x:.2f}, y = {y:.2f})")


# ------------------------------------------------------------------------------------ speed
@dataclass
class SpeedProfile:
    """Piecewise constant speed along the route: ``breaks`` (arclengths, ascending, first 0) and
    the speed (m/s) from each break to the next."""

    breaks: np.ndarray
    speeds: np.ndarray
    source: str = "constant"

    def pieces(self, length_m: float) -> list[tuple[float, float, float]]:
        """(s0, s1, speed) stretches up to ``length_m``."""
        ends = np.append(self.breaks[1:], np.inf)
        out = []
        for a, b, v in zip(self.breaks, ends, self.speeds):
            if a >= length_m:
                break
            out.append((float(a), float(min(b, length_m)), float(v)))
        return out


def constant_speed(kmh: float) -> SpeedProfile:
    if not (math.isfinite(kmh) and 1.0 <= kmh <= 200.0):
        raise RoadtwinError(f"--speed must be in [1, 200] km/h, got {kmh}")
    return SpeedProfile(np.array([0.0]), np.array([kmh / 3.6]), f"{kmh:g} km/h")


def read_recommendations(path: Path, vehicle_name: str) -> dict[str, float]:
    """{defect id: recommended speed (m/s)} for ``vehicle_name`` from a sweep's
    ``recommendations.json``; one line when the file is not one, or is for another vehicle."""
    path = Path(path)
    try:
        recs = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise RoadtwinError(f"speed profile {path}: not a sweep's recommendations.json ({str(exc).splitlines()[0]})") from None
    if not isinstance(recs, list) or not all(isinstance(r, dict) and "defect" in r and "vehicle" in r for r in recs):
        raise RoadtwinError(f"speed profile {path}: not a sweep's recommendations.json (a list of "
                            f"{{defect, vehicle, recommended_speed_kmh}})")
    vehicles = sorted({str(r["vehicle"]) for r in recs})
    if vehicle_name not in vehicles:
        raise RoadtwinError(f"speed profile {path}: is for vehicle {', '.join(vehicles)}, this drive uses {vehicle_name!r}")
    rec: dict[str, float] = {}
    for r in recs:
        v = r.get("recommended_speed_kmh")
        if r["vehicle"] == vehicle_name and v is not None:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and 1 <= v <= 200):
                raise RoadtwinError(f"speed profile {path}: defect {r['defect']}: recommended_speed_kmh must be in "
                                    f"[1, 200], got {v!r}")
            rec[str(r["defect"])] = min(rec.get(str(r["defect"]), np.inf), float(v) / 3.6)
    return rec


def speed_profile(rec: dict[str, float], hits: list[dict], cruise_kmh: float, source: str = "recommendations",
                  slow_before_m: float = 10.0, slow_after_m: float = 3.0) -> SpeedProfile:
    """Cruise at ``cruise_kmh``; over each defect of ``hits`` its recommended speed from ``rec``
    (:func:`read_recommendations`), from ``slow_before_m`` before it to ``slow_after_m`` after."""
    cruise = constant_speed(cruise_kmh).speeds[0]
    zones = sorted((h["s"] - slow_before_m, h["s"] + slow_after_m, rec[h["id"]]) for h in hits if h["id"] in rec)
    breaks, speeds = [0.0], [cruise]
    for a, b, v in zones:
        a = max(a, breaks[-1])
        if b <= a:
            continue
        if a > breaks[-1]:
            breaks.append(a)
            speeds.append(v)
        else:
            speeds[-1] = min(speeds[-1], v) if len(breaks) > 1 else v
        breaks.append(b)
        speeds.append(cruise)
    return SpeedProfile(np.array(breaks), np.array(speeds), f"{source}: {len(zones)} defect(s) at the sweep's speed")


def load_speed_profile(path: Path, vehicle_name: str, hits: list[dict], cruise_kmh: float) -> SpeedProfile:
    """:func:`read_recommendations` then :func:`speed_profile`."""
    return speed_profile(read_recommendations(path, vehicle_name), hits, cruise_kmh, Path(path).name)
