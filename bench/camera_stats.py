"""Camera statistics of real survey frames, the randomizer's targets, and the same statistics
of synthetic frames beside them.

    PYTHONPATH=. .venv/bin/python bench/camera_stats.py                      # measure train, write targets
    PYTHONPATH=. .venv/bin/python bench/camera_stats.py --synthetic OUT      # + compare a render's frames

Reads ONLY the train split (``../shared/data/road_defects_br/train`` at 512x320 with its labels;
``train_full`` at the camera's own 1024x640/630 JPEG bytes for sharpness, noise and JPEG). A path
with a ``val`` or ``test`` component is refused: targets are never fitted on evaluation frames.

Per frame (regions from the labels: *road* = the ego lane, class 1; *side* = background, class 0;
the survey camera looks 25 deg down, its horizon lies ~48 px above the picture: there is no sky):

* colour: per-channel mean and std (sRGB 0-255) of the road, the side and the whole frame; the
  road's linear chromaticity r/g, b/g (white balance: the asphalt is close to neutral); mean HSV
  saturation (0-1); mean linear luminance of the frame (exposure);
* contrast: RMS contrast (std / mean of luma) and the 5-95 % luma spread;
* sharpness: variance of the Laplacian of luma on the road, and an MTF50 proxy: the share of the
  road's luma power spectrum above 0.25 cycles/px among that above 0.05 (scale-free, less
  scene-dependent than the Laplacian);
* noise: Immerkaer's estimator (the |Laplacian-difference| mask, sqrt(pi/2)/6 normalisation) on
  the flattest 30 % of road pixels (Sobel magnitude), in 8-bit levels;
* vignetting: a per-frame fit of ``log L = c(row) + s * log cos^4(theta)`` on road pixels (within
  each row: the scene changes mostly with the distance, i.e. the row, so the row term absorbs it),
  ``theta`` from the survey rig's 60 deg field of view; ``s`` is the randomizer's ``vignetting``;
* JPEG: quality estimated from the luminance quantization table (PIL ``img.quantization``) as the
  IJG quality whose scaled standard table is closest.

Targets (``roadtwin_core/render/camera_targets/road_defects_br.json``): the real frames'
quantiles (p10 / p50 / p90) and the randomizer ranges derived from them (``ranges``: field
names of :class:`roadtwin_core.render.randomize.Ranges`). With ``--synthetic``, the optics blur
(Gaussian sigma) that brings the synthetic frames' MTF50 proxy to the real median is solved for
too, and the saturation ratio real / synthetic.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.ndimage import convolve, gaussian_filter, laplace, sobel

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared/data/road_defects_br"
TARGETS = ROOT / "roadtwin_core/render/camera_targets/road_defects_br.json"
HFOV_DEG = 60.0          # the survey rig's assumed field of view (docs/survey_rig.md)
ROAD, SIDE = 1, 0

# IJG standard luminance quantization table (JPEG Annex K), natural (row-major) order
_STD_LUMA = np.array([16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
                      14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
                      49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99], float)
# PIL's quantization tables are in zigzag order
_ZIGZAG = np.array([0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5, 12, 19, 26, 33, 40, 48, 41, 34, 27, 20, 13,
                    6, 7, 14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22, 15, 23, 30, 37, 44, 51, 58, 59, 52, 45,
                    38, 31, 39, 46, 53, 60, 61, 54, 47, 55, 62, 63])


def refuse_eval(path: Path) -> Path:
    parts = {p.lower() for p in Path(path).resolve().parts}
    if parts & {"val", "test", "valid", "validation"}:
        sys.exit(f"camera_stats: {path}: refusing an evaluation split (train only)")
    return Path(path)


def srgb_to_linear(x8: np.ndarray) -> np.ndarray:
    x = x8.astype(np.float64) / 255.0
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def luma(rgb8: np.ndarray) -> np.ndarray:
    return rgb8.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


def jpeg_quality(path: Path) -> float | None:
    """IJG quality whose scaled standard luminance table is closest (L1 in log) to the file's."""

    with Image.open(path) as im:
        q = getattr(im, "quantization", None)
    if not q:
        return None
    table = np.zeros(64)
    table[_ZIGZAG] = np.asarray(q[0], float)        # natural order
    best, err = None, math.inf
    for quality in range(1, 101):
        scale = 5000.0 / quality if quality < 50 else 200.0 - 2.0 * quality
        ref = np.clip(np.floor((_STD_LUMA * scale + 50.0) / 100.0), 1, 255)
        e = float(np.abs(np.log(ref) - np.log(table)).mean())
        if e < err:
            best, err = quality, e
    return float(best)


def noise_sigma(y: np.ndarray, mask: np.ndarray, flat_share: float = 0.3) -> float:
    """Immerkaer (1996) on the flattest pixels of ``mask``: sigma in the image's units."""

    m = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], float)
    r = np.abs(convolve(y, m, mode="reflect"))
    g = np.hypot(sobel(y, 0), sobel(y, 1))
    inner = mask.copy()
    inner[:2], inner[-2:], inner[:, :2], inner[:, -2:] = False, False, False, False
    if inner.sum() < 500:
        return float("nan")
    cut = np.quantile(g[inner], flat_share)
    sel = inner & (g <= cut)
    return float(math.sqrt(math.pi / 2) / 6.0 * r[sel].mean())


def mtf_proxy(y: np.ndarray, mask: np.ndarray) -> float:
    """Share of luma power above 0.25 cycles/px among that above 0.05, over the mask's bounding
    box (mask outside filled with its mean; Hann window)."""
    rows, cols = np.nonzero(mask)
    if len(rows) < 500:
        return float("nan")
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    patch = y[r0:r1, c0:c1].copy()
    m = mask[r0:r1, c0:c1]
    patch[~m] = patch[m].mean()
    patch -= patch.mean()
    patch *= np.outer(np.hanning(patch.shape[0]), np.hanning(patch.shape[1]))
    p = np.abs(np.fft.rfft2(patch)) ** 2
    fy = np.fft.fftfreq(patch.shape[0])[:, None]
    fx = np.fft.rfftfreq(patch.shape[1])[None, :]
    f = np.hypot(fy, fx)
    lo = p[f > 0.05].sum()
    return float(p[f > 0.25].sum() / lo) if lo > 0 else float("nan")


def vignetting_fit(lin_y: np.ndarray, mask: np.ndarray, hfov_deg: float = HFOV_DEG) -> tuple[float, float]:
    """Normal equations (a.b, a.a) of ``log L = c(row) + s * log cos^4(theta)`` over ``mask``
    pixels: ``s`` = a.b / a.a for one frame; summed over frames, the pooled fit."""
    h, w = lin_y.shape
    f = (w / 2) / math.tan(math.radians(hfov_deg) / 2)
    u, v = np.meshgrid(np.arange(w) - (w - 1) / 2, np.arange(h) - (h - 1) / 2)
    logv = -2.0 * np.log1p((u * u + v * v) / (f * f))          # log cos^4 theta
    ll = np.log(np.maximum(lin_y, 1e-4))
    num = den = 0.0
    for row in range(h):
        sel = mask[row]
        if sel.sum() < 20:
            continue
        a = logv[row, sel] - logv[row, sel].mean()
        b = ll[row, sel] - ll[row, sel].mean()
        num += float(a @ b)
        den += float(a @ a)
    return num, den


def measure(rgb8: np.ndarray, labels: np.ndarray | None) -> dict:
    """Statistics of one frame (see the module docstring); ``labels`` in road_defects_br ids."""

    y = luma(rgb8)
    lin = srgb_to_linear(rgb8)
    lin_y = lin @ np.array([0.2126, 0.7152, 0.0722])
    road = (labels == ROAD) if labels is not None else np.ones(y.shape, bool)
    side = (labels == SIDE) if labels is not None else np.zeros(y.shape, bool)
    out: dict = {}
    for name, m in (("frame", np.ones(y.shape, bool)), ("road", road), ("side", side)):
        if m.sum() < 100:
            continue
        px = rgb8[m].astype(np.float64)
        out[f"{name}_mean"] = px.mean(axis=0).tolist()
        out[f"{name}_std"] = px.std(axis=0).tolist()
    mx, mn = rgb8.max(axis=2).astype(float), rgb8.min(axis=2).astype(float)
    out["saturation"] = float(np.where(mx > 0, (mx - mn) / np.maximum(mx, 1), 0).mean())
    if road.sum() >= 100:
        rl = lin[road].mean(axis=0)
        out["road_r_g"], out["road_b_g"] = float(rl[0] / rl[1]), float(rl[2] / rl[1])
        out["road_lin_luminance"] = float(lin_y[road].mean())
    out["frame_lin_luminance"] = float(lin_y.mean())
    out["rms_contrast"] = float(y.std() / max(y.mean(), 1e-6))
    p5, p95 = np.percentile(y, [5, 95])
    out["luma_spread_5_95"] = float(p95 - p5)
    core = road.copy()
    core[:1], core[-1:], core[:, :1], core[:, -1:] = False, False, False, False
    out["laplacian_var"] = float(laplace(y)[core].var()) if core.sum() > 100 else float("nan")
    out["mtf_proxy"] = mtf_proxy(y, road)
    out["noise_sigma"] = noise_sigma(y, road)
    num, den = vignetting_fit(lin_y, road)
    out["vignetting"] = num / den if den > 0 else float("nan")
    out["_vig_num"], out["_vig_den"] = num, den
    if "road_r_g" in out:   # white-balance gains (1+t, 1+k, 1-t) that make a neutral road look like this one
        r, b = out["road_r_g"], out["road_b_g"]
        out["wb_temperature"], out["wb_tint"] = (r - b) / (r + b), 2.0 / (r + b) - 1.0
    return out


def _read(path: Path) -> np.ndarray:

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _labels_for(img: Path, label_dir: Path) -> np.ndarray | None:

    p = label_dir / (img.stem + ".png")
    if not p.is_file():
        return None
    with Image.open(p) as im:
        return np.asarray(im)


def measure_split(images: list[Path], label_dir: Path | None, with_jpeg: bool = True) -> list[dict]:
    rows = []
    for p in images:
        rgb = _read(p)
        lab = _labels_for(p, label_dir) if label_dir else None
        if lab is not None and lab.shape != rgb.shape[:2]:
            lab = None
        s = measure(rgb, lab)
        if with_jpeg:
            s["jpeg_quality"] = jpeg_quality(p)
        s["size"] = [int(rgb.shape[1]), int(rgb.shape[0])]
        rows.append(s)
    return rows


def synthetic_frames(out: Path, limit: int) -> tuple[list[Path], dict[str, Path]]:
    """A roadtwin render folder (meta.json): its images and class-mapped labels."""
    meta = json.loads((out / "meta.json").read_text())
    imgs, labs = [], {}
    for fr in meta["frames"][:limit]:
        p = out / fr["files"]["rgb"]
        imgs.append(p)
        labs[p.stem] = out / fr["files"]["semantic"]
    return imgs, labs


def quantiles(rows: list[dict], key: str, idx: int | None = None, q=(10, 50, 90)) -> list[float]:
    vals = [r[key] if idx is None else r[key][idx] for r in rows if key in r and r[key] is not None]
    vals = np.asarray(vals, float)
    vals = vals[np.isfinite(vals)]
    return [round(float(v), 4) for v in np.percentile(vals, q)] if len(vals) else [float("nan")] * len(q)


SCALAR_KEYS = ("saturation", "rms_contrast", "luma_spread_5_95", "frame_lin_luminance", "road_lin_luminance",
               "road_r_g", "road_b_g", "wb_temperature", "wb_tint", "laplacian_var", "mtf_proxy", "noise_sigma", "vignetting", "jpeg_quality")


def summarise(rows: list[dict]) -> dict:
    s = {k: quantiles(rows, k) for k in SCALAR_KEYS}
    for region in ("frame", "road", "side"):
        for stat in ("mean", "std"):
            k = f"{region}_{stat}"
            if any(k in r for r in rows):
                s[k] = {c: quantiles(rows, k, i) for i, c in enumerate("rgb")}
    den = sum(r.get("_vig_den", 0.0) for r in rows)
    s["vignetting_pooled"] = round(sum(r.get("_vig_num", 0.0) for r in rows) / den, 4) if den > 0 else float("nan")
    s["frames"] = len(rows)
    return s


def derive_ranges(small: dict, full: dict) -> dict:
    """Randomizer ``Ranges`` fields from the real quantiles (p10..p90 of each frame statistic).

    * ``wb_temperature`` / ``wb_tint``: the gains (1+t, 1+k, 1-t) that turn a neutral asphalt
      into the road's measured r/g and b/g: t = (r - b) / (r + b), k = 2 / (r + b) - 1 (ratios to g);
    * ``vignetting``: 0 .. twice the pooled fit of the cos^4 exponent scale (per-frame fits are
      noisy: the lane's own lateral shading leaks in; at least 0.05);
    * ``jpeg_quality``: the frames' own estimate at the size a network sees (512x320: the
      dataset's re-encode); ``camera_jpeg_quality`` (not a Ranges field) records the camera's;
    * ``read_noise``: the flat-road noise sigma taken back through the sRGB curve at the road's
      median level (a lower bound: JPEG has smoothed some of it away);
    * ``frame_luminance``: the frame's mean linear luminance (the target of an auto-exposure);
      ``exposure_ev`` then (0, 0): the target's spread is the real frames' own.
    """
    lum = small["road_lin_luminance"][1]
    slope = 1.055 / 2.4 * lum ** (1 / 2.4 - 1) * 255.0            # sRGB levels per linear unit at that level
    noise = [s / slope for s in small["noise_sigma"]]
    vig = max(small["vignetting_pooled"], 0.0)
    q = small["jpeg_quality"]
    return {"wb_temperature": [small["wb_temperature"][0], small["wb_temperature"][2]],
            "wb_tint": [small["wb_tint"][0], small["wb_tint"][2]],
            "vignetting": [0.0, round(max(2.0 * vig, 0.05), 3)],
            "jpeg_quality": [int(q[0]), int(q[2])],
            "read_noise": [round(max(noise[0], 0.0), 5), round(max(noise[2], 0.0), 5)],
            "frame_luminance": [round(v, 4) for v in small["frame_lin_luminance"][::2]],
            "exposure_ev": [0.0, 0.0],        # the auto-exposure target carries the real spread
            "camera_jpeg_quality": [int(v) for v in full["jpeg_quality"][::2]] if "jpeg_quality" in full else None}


def solve_blur(synth_imgs: list[Path], synth_labels: dict, target: float) -> float:
    """Gaussian sigma (px) that brings the synthetic frames' median MTF proxy to ``target``."""

    frames = []
    for p in synth_imgs:
        lab = _read_label(synth_labels[p.stem])
        frames.append((luma(_read(p)), lab == ROAD))

    def med(sigma):
        return float(np.nanmedian([mtf_proxy(gaussian_filter(y, sigma) if sigma > 0 else y, m) for y, m in frames]))

    if med(0.0) <= target:
        return 0.0
    lo, hi = 0.0, 3.0
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if med(mid) > target else (lo, mid)
    return round(0.5 * (lo + hi), 3)


def _read_label(p: Path) -> np.ndarray:

    with Image.open(p) as im:
        return np.asarray(im)


def _row(name: str, real: list, synth: list | None, fmt: str = "{:.3f}") -> str:
    f = lambda q: " / ".join(fmt.format(v) for v in q)   # noqa: E731
    return f"{name:<24} {f(real):<30} {f(synth) if synth else '':<30}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--real", type=Path, default=DATA / "train", help="train split at 512x320 (images/, labels/)")
    ap.add_argument("--full", type=Path, default=DATA / "train_full", help="train at full res (images/)")
    ap.add_argument("--synthetic", type=Path, default=None, help="a roadtwin render folder (meta.json) to compare")
    ap.add_argument("--limit", type=int, default=0, help="at most this many real frames (every k-th; 0 = all)")
    ap.add_argument("-o", "--out", type=Path, default=TARGETS, help="targets JSON to write ('-': none)")
    a = ap.parse_args(argv)
    real, full = refuse_eval(a.real), refuse_eval(a.full)
    imgs = sorted((real / "images").glob("*.jpg"))
    fimgs = sorted((full / "images").glob("*.jpg"))
    if a.limit and len(imgs) > a.limit:
        imgs = imgs[:: len(imgs) // a.limit][: a.limit]
        fimgs = fimgs[:: max(1, len(fimgs) // a.limit)][: a.limit]
    small = summarise(measure_split(imgs, real / "labels"))
    fulls = summarise(measure_split(fimgs, full / "labels"))
    ranges = derive_ranges(small, fulls)
    synth = None
    if a.synthetic:
        simgs, slabs = synthetic_frames(a.synthetic, 64)
        rows = []
        for p in simgs:
            s = measure(_read(p), _read_label(slabs[p.stem]))
            s["jpeg_quality"] = jpeg_quality(p) if p.suffix.lower() in (".jpg", ".jpeg") else None
            rows.append(s)
        synth = summarise(rows)
        ranges["optics_blur_px"] = [0.0, solve_blur(simgs, slabs, small["mtf_proxy"][1])]
        # frames already rendered with a saturation gain: the ratio corrects that gain (iterate)
        meta = json.loads((a.synthetic / "meta.json").read_text())
        gains = [fr.get("randomization", {}).get("effects", {}).get("saturation", 1.0) for fr in meta["frames"]]
        ranges["saturation"] = round(float(np.median(gains)) * small["saturation"][1] / max(synth["saturation"][1], 1e-6), 3)
    print(f"real: {small['frames']} train frames {imgs[0].parent if imgs else ''}; full res: {fulls['frames']}"
          + (f"; synthetic: {synth['frames']} frames {a.synthetic}" if synth else ""))
    print(f"{'statistic (p10/p50/p90)':<24} {'real train (512x320)':<30} {'synthetic' if synth else '':<30}")
    for k in SCALAR_KEYS:
        print(_row(k, small[k], synth.get(k) if synth else None))
    for region in ("road", "side", "frame"):
        for stat in ("mean", "std"):
            k = f"{region}_{stat}"
            for c in "rgb":
                if k in small:
                    print(_row(f"{k}[{c}]", small[k][c], synth[k][c] if synth and k in synth else None, "{:.1f}"))
    print(f"{'full res (train_full)':<24}")
    for k in ("laplacian_var", "mtf_proxy", "noise_sigma", "vignetting", "jpeg_quality"):
        print(_row("  " + k, fulls[k], None))
    print(f"vignetting pooled fit: real {small['vignetting_pooled']} (full res {fulls['vignetting_pooled']})"
          + (f", synthetic {synth['vignetting_pooled']}" if synth else ""))
    print("ranges:", json.dumps(ranges))
    if str(a.out) != "-":
        a.out.parent.mkdir(parents=True, exist_ok=True)
        doc = {"name": "road_defects_br", "source": "bench/camera_stats.py on road_defects_br train (never val)",
               "hfov_deg": HFOV_DEG, "quantiles": [10, 50, 90], "real": small, "real_full_res": fulls,
               "ranges": ranges}
        if synth:
            doc["synthetic"] = {"source": str(a.synthetic), **synth}
        a.out.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
        print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
