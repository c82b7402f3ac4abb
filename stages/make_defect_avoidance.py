"""Generate stages/defect_avoidance.usda, the path-planning scenario of Zhang et al.

A straight two-lane road, 110 m along +x, lanes 3.5 m (right lane y in [-3.5, 0], travel +x;
left lane y in [0, 3.5]), 2 m sidewalks on both sides, split every 22 m. The vehicle (track
2.0 m, wheelbase 3.0 m, 2.2 m over the tires) starts in the right lane at x = 4 m and has to
reach x = 105 m in the same lane. The defects are pinned (``FixedDefect``), laid out so that
the decisions the paper discusses all occur:

* ``straddle_a/b/c``: narrow potholes (0.6 m across) on the right lane's centre line. With
  wheel-level collision the vehicle keeps its line and lets them pass between its wheels (inner
  gap = track - tire width = 1.8 m); a body has to move about 1.5 m to the left.
* ``centre_line_a/b`` with ``edge_a/b``: a pothole on the lane divider plus one near the left
  road edge at the same x. Harmless for wheels that stay on the right lane's centre line, but
  they send a body that fled a straddle pothole back into the right lane: a body-level planner
  has to slalom, a wheel-level one drives straight.
* ``wide_depression``: a 3 m wide settlement across the right lane that nothing can straddle:
  every planner has to bypass it through the left lane.
* ``right_wheel``: a pothole under the right wheel path: a small shift (or a straddle) for wheels.

Markings: a broken yellow centre line on y = 0 (passing allowed: the wide depression has to be
bypassed through the left lane; 0.125 m, 3 m dashes, 9 m gaps like the sample town) and solid
white edge lines (0.12 m) on the lane/sidewalk borders y = -3.5 and y = 3.5. The
``centre_line_a/b`` potholes sit on the centre line's paint.

Rules: no random defects (``defect_count = 0``), flat surface. The layout carries the default
route as metadata ``roadtwin:layout:planStart`` / ``planGoal`` ("x,y,yaw", radians), which
``roadtwin plan`` uses when --start/--goal are omitted.
Run: ``python stages/make_defect_avoidance.py`` (output is deterministic).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import triangle

from roadtwin_core import ComposeRules, FixedDefect, LaneMarking, RoadSegment, TownLayout
from roadtwin_core.usd import write_layout

LENGTH, LANE, WALK, SPLIT = 110.0, 3.5, 2.0, 22.0
START = (4.0, -1.75, 0.0)
GOAL = (105.0, -1.75, 0.0)


def _mesh(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = len(poly)
    seg = np.column_stack([np.arange(n), (np.arange(n) + 1) % n])
    t = triangle.triangulate({"vertices": poly, "segments": seg}, "p")
    return t["vertices"], t["triangles"]


def _strip(x0: float, x1: float, y0: float, y1: float, step: float = 2.5) -> np.ndarray:
    """A rectangle outline with its long sides sampled every ``step`` (so neighbouring pieces
    share border vertices exactly and the triangles stay reasonably shaped)."""
    xs = np.linspace(x0, x1, int(round((x1 - x0) / step)) + 1)
    bottom = np.column_stack([xs, np.full_like(xs, y0)])
    top = np.column_stack([xs[::-1], np.full_like(xs, y1)])
    return np.concatenate([bottom, top])


def markings(step: float = 2.5) -> list[LaneMarking]:
    """Sampled every ``step`` like the segment borders, so a draped line can follow the road."""
    xs = np.linspace(0.0, LENGTH, int(round(LENGTH / step)) + 1)

    def along(y: float) -> np.ndarray:
        return np.column_stack([xs, np.full_like(xs, y)])

    return [LaneMarking("centre", "broken", "yellow", 0.125, along(0.0), 3.0, 9.0),
            LaneMarking("edge_right", "solid", "white", 0.12, along(-LANE)),        # travel +x
            LaneMarking("edge_left", "solid", "white", 0.12, along(LANE)[::-1])]    # travel -x


def pothole(radius: float, depth: float = 0.06) -> dict:
    # Round and regular, so the footprint is predictable: ~2 * radius across.
    return {"radius_m": radius, "depth_m": depth, "elongation": 1.0, "irregularity": 0.08,
            "roughness_m": 0.003}


def defects() -> list[FixedDefect]:
    small = pothole(0.25, 0.05)
    return [
        FixedDefect("straddle_a", "pothole", pothole(0.30), 14.0, -1.75, 0.0, seed=1),
        FixedDefect("centre_line_a", "pothole", small, 26.0, -0.1, 0.0, seed=2),
        FixedDefect("edge_a", "pothole", small, 26.0, 2.5, 0.0, seed=3),
        FixedDefect("straddle_b", "pothole", pothole(0.30, 0.08), 38.0, -1.75, 0.0, seed=4),
        FixedDefect("centre_line_b", "pothole", small, 50.0, -0.1, 0.0, seed=5),
        FixedDefect("edge_b", "pothole", small, 50.0, 2.5, 0.0, seed=6),
        FixedDefect("wide_depression", "depression", {"length_m": 2.5, "width_m": 3.0, "depth_m": 0.04},
                    64.0, -1.6, 0.0, seed=7),
        FixedDefect("straddle_c", "pothole", pothole(0.30), 78.0, -1.75, 0.0, seed=8),
        FixedDefect("right_wheel", "pothole", pothole(0.25, 0.07), 90.0, -2.75, 0.0, seed=9),
    ]


def build() -> TownLayout:
    bands = [(-LANE - WALK, -LANE, "sidewalk"), (-LANE, 0.0, "driving"), (0.0, LANE, "driving"),
             (LANE, LANE + WALK, "sidewalk")]
    segs = []
    for piece, x0 in enumerate(np.arange(0.0, LENGTH, SPLIT)):
        for k, (y0, y1, kind) in enumerate(bands):
            v, f = _mesh(_strip(x0, x0 + SPLIT, y0, y1))
            y = 0.5 * (y0 + y1)
            # Right-hand traffic: the right lane runs +x, the left lane -x.
            center = np.array([[x0, y], [x0 + SPLIT, y]]) if y < 0 else np.array([[x0 + SPLIT, y], [x0, y]])
            segs.append(RoadSegment(f"road_{piece:02d}_{k}", kind, v, f, center if kind == "driving" else None,
                                    {"road": "main"}))
    rules = ComposeRules(defect_count=0, seed=0, surface="flat", merger="cdt", kinds=("driving",))
    meta = {"planStart": ",".join(f"{v:g}" for v in START), "planGoal": ",".join(f"{v:g}" for v in GOAL),
            "scenario": "defect avoidance (Zhang et al.): straddle, slalom, wide and wheel-path defects"}
    return TownLayout("Town", segs, rules, fixed=defects(), metadata=meta, markings=markings())


if __name__ == "__main__":
    out = Path(__file__).with_name("defect_avoidance.usda")
    write_layout(build(), out, "roadtwin path-planning scenario: straight road with defects (synthetic, CC0)")
    print(f"wrote {out}")
