"""How a photo library's potholes were given relief: bowls against wheel-path strips (issue 22).

``roadtwin reconstruct photos`` gives a pothole label a depth prior: a bowl (depth from the radius
of a disc of its area) or, when the label is a strip along travel (ravelled or patched wheel
paths, labelled pothole by some surveys), the lost surface course (at most 3 cm). This prints,
per road of the source frames and relief, the instances, their share of the footprint area and
the median prior depth and footprint::

    .venv/bin/roadtwin reconstruct photos ../shared/data/road_defects_br/train_full/images \\
        --labels ../shared/data/road_defects_br/train_full/labels -o /tmp/photo_lib
    .venv/bin/python bench/photo_relief.py /tmp/photo_lib
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from roadtwin_core.apps.library import read_interface  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _perception_data import frame_stem, road_of  # noqa: E402


def relief_rows(library: Path) -> list[dict]:
    """One row per (road, relief) of the library's pothole assets."""
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for asset in sorted(library.glob("*.usda")):
        if asset.name.endswith(".geom.usda"):
            continue
        params = json.loads(read_interface(asset).attrs.get("roadtwin:params") or "{}")
        if params.get("class") != "pothole" or "relief" not in params:
            continue
        groups[(road_of(frame_stem(params["frame"])), params["relief"])].append(params)
    total = defaultdict(float)
    for (road, _), ps in groups.items():
        total[road] += sum(p["footprint_area_m2"] for p in ps)
    return [{"road": road, "relief": relief, "instances": len(ps),
             "area_share": sum(p["footprint_area_m2"] for p in ps) / total[road],
             "depth_median_m": float(np.median([p["prior_depth_m"] for p in ps])),
             "area_median_m2": float(np.median([p["footprint_area_m2"] for p in ps]))}
            for (road, relief), ps in sorted(groups.items())]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("library", type=Path, help="a library folder written by roadtwin reconstruct photos")
    rows = relief_rows(ap.parse_args().library)
    print("| road | relief | pothole instances | share of the road's pothole area | median prior depth | median footprint |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['road']} | {r['relief']} | {r['instances']} | {100 * r['area_share']:.0f} % | "
              f"{100 * r['depth_median_m']:.1f} cm | {r['area_median_m2']:.2f} m^2 |")


if __name__ == "__main__":
    main()
