"""Domain randomization: per-frame render parameters, scene-look choices and an image-space
camera model, all a pure function of ``(seed, frame index)``.

Why: a network trained on one sun, one exposure and noise-free renders learns the renderer, not
the road. Real survey frames (road_defects_br) differ in sun position, white balance, exposure,
sensor noise, motion blur at the bottom of the frame, vignetting and JPEG artefacts; drawing
those per frame makes the synthetic set cover them.

Three parts, drawn together by :func:`draw` (frame ``i`` uses ``default_rng([seed, i, stream])``
and nothing else, so frames rendered on different workers or in another order come out the same):

* ``RenderParams`` the renderer understands today: sun elevation and azimuth, weather (mostly
  clear, some wet), wetness, haze (fog density);
* :class:`SceneLook`: sky tint, road wear and colour tint, shoulder and verge surfaces (catalog
  material names), applied by the renderer through :mod:`.scene_look`; wet patches are drawn
  and recorded but not rendered yet;
* :class:`ImageEffects` applied to the rendered *linear* RGB by :func:`apply_sensor`, in the
  order light goes through a camera: motion blur (integration over the exposure while the car
  moves) -> optics blur -> vignetting (optics) -> auto-exposure -> exposure -> photon (Poisson) +
  read (Gaussian) noise on the sensor -> white-balance gains and saturation (ISP) -> tone curve
  and sRGB -> 8 bit -> JPEG. Labels, depth and every other annotation stay untouched (a blurred
  label would be a wrong label).

Camera targets (:meth:`Ranges.from_targets`): ranges measured from a dataset's real train frames
by ``bench/camera_stats.py`` (``camera_targets/<name>.json``, selected by a class map's
``camera_targets`` key). Optics blur, saturation and the auto-exposure target are identity
unless a targets file sets them, and they draw from a stream of their own, so a render without
targets is byte-identical to one made before they existed.
"""
from __future__ import annotations

import functools
import io
import json
import math
from importlib import resources
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np
from PIL import Image

from ..errors import RoadtwinError
from .cameras import Camera, pixel_grid
from .frames import RenderParams
from .tonemap import to_srgb8

_STREAM_DRAW, _STREAM_NOISE = 0, 1
_LUMA = (0.2126, 0.7152, 0.0722)          # Rec. 709 luminance of linear RGB


@dataclass(frozen=True)
class Ranges:
    """What :func:`draw` samples from (uniform unless said otherwise)."""

    sun_elevation_deg: tuple[float, float] = (15.0, 75.0)
    wet_probability: float = 0.12                 # weather "wet" (overcast, soaked) instead of "clear"
    wetness: tuple[float, float] = (0.4, 1.0)     # when wet
    haze_density: tuple[float, float] = (0.0, 0.004)   # 1/m exponential fog on clear days
    wet_patch_probability: float = 0.25           # dry road with damp patches
    wet_patch_coverage: tuple[float, float] = (0.05, 0.3)
    exposure_ev: tuple[float, float] = (-0.6, 0.6)
    wb_temperature: tuple[float, float] = (-0.12, 0.12)   # red up / blue down when positive
    wb_tint: tuple[float, float] = (-0.04, 0.04)          # green
    gain: tuple[float, float] = (1 / 3000, 1 / 300)       # photon noise: variance = gain * signal
    read_noise: tuple[float, float] = (0.0005, 0.005)     # std, linear units
    speed_mps: tuple[float, float] = (8.0, 25.0)          # survey vehicle speed
    exposure_time_s: tuple[float, float] = (1 / 2000, 1 / 125)   # log-uniform
    vignetting: tuple[float, float] = (0.2, 1.0)          # exponent scale of cos^4 falloff
    jpeg_quality: tuple[int, int] = (60, 95)               # inclusive
    sky_tint: tuple[float, float] = (-0.08, 0.08)
    road_wear: tuple[float, float] = (0.0, 1.0)
    road_tint: tuple[float, float] = (-0.06, 0.06)
    # catalog material names (roadtwin_core.looks): the paved shoulder twice as often as the others;
    # verges mostly grass, some gravel, some red lateritic soil (Brazilian roadsides)
    shoulder_surfaces: tuple[str, ...] = ("shoulder", "shoulder", "asphalt_worn", "gravel")
    verge_surfaces: tuple[str, ...] = ("grass", "grass", "gravel", "soil")
    pothole_brightness: tuple[float, float] = (0.6, 2.4)  # log-uniform multiplier of the interior's albedo
    pothole_warmth: tuple[float, float] = (0.0, 0.3)      # red up, blue down: exposed lateritic base course
    pothole_wet_probability: float = 0.15                 # the glossy, darker wet interior
    # Camera targets (bench/camera_stats.py): identity unless a targets file sets them
    saturation: tuple[float, float] = (1.0, 1.0)          # ISP saturation (mix with luminance, linear)
    optics_blur_px: tuple[float, float] = (0.0, 0.0)      # Gaussian sigma of the lens + demosaic blur
    frame_luminance: tuple[float, float] | None = None    # auto-exposure: the frame's mean linear luminance

    @classmethod
    def from_targets(cls, spec: str | Path, base: "Ranges | None" = None) -> "Ranges":
        """``base`` (default: these defaults) with the ``ranges`` of a camera targets file, a
        path or a built-in name (``roadtwin_core/render/camera_targets/<name>.json``, written by
        ``bench/camera_stats.py`` from real frames). Keys that are not fields are records only."""
        path = Path(spec)
        if path.suffix != ".json" and not path.exists():
            res = resources.files(__package__).joinpath("camera_targets", f"{spec}.json")
            if not res.is_file():
                raise RoadtwinError(f"no camera targets {str(spec)!r}: not a file, nor a built-in one")
            text, source = res.read_text(encoding="utf-8"), f"{spec} (built-in)"
        else:
            try:
                text, source = path.read_text(encoding="utf-8"), str(path)
            except (OSError, UnicodeDecodeError) as exc:
                raise RoadtwinError(f"{path}: cannot read the camera targets ({exc})") from None
        try:
            found = json.loads(text)["ranges"]
        except (ValueError, KeyError, TypeError):
            raise RoadtwinError(f"{source}: not a camera targets file (no 'ranges' table)") from None
        names = {f.name: f for f in fields(cls)}
        changes = {}
        for key, value in found.items():
            if key not in names or value is None:
                continue
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                value = [value, value]                                  # a measured ratio: no spread
            if not (isinstance(value, list) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value)):
                raise RoadtwinError(f"{source}: ranges.{key} must be [lo, hi], got {value!r}")
            lo, hi = value
            if not lo <= hi:
                raise RoadtwinError(f"{source}: ranges.{key} must have lo <= hi, got {value!r}")
            changes[key] = (int(lo), int(hi)) if key == "jpeg_quality" else (float(lo), float(hi))
        return replace(base or cls(), **changes).check()

    def check(self) -> "Ranges":
        lo, hi = self.jpeg_quality
        if not (1 <= lo <= hi <= 100):
            raise RoadtwinError(f"randomization: JPEG quality range must lie in 1..100, got {self.jpeg_quality}")
        lo, hi = self.sun_elevation_deg
        if not (-10.0 <= lo <= hi <= 90.0):
            raise RoadtwinError(f"randomization: sun elevation range must lie in -10..90 degrees, got {self.sun_elevation_deg}")
        for name in ("wet_probability", "wet_patch_probability", "pothole_wet_probability"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise RoadtwinError(f"randomization: {name} must be in [0, 1], got {getattr(self, name)}")
        if min(self.gain) < 0 or min(self.read_noise) < 0 or min(self.exposure_time_s) <= 0:
            raise RoadtwinError("randomization: noise gains, read noise and exposure times must be >= 0 (> 0 for times)")
        if min(self.saturation) < 0 or min(self.optics_blur_px) < 0 or (
                self.frame_luminance is not None and min(self.frame_luminance) <= 0):
            raise RoadtwinError("randomization: saturation and optics blur must be >= 0, frame luminance > 0")
        return self


@dataclass(frozen=True)
class SceneLook:
    """Appearance choices for the scene's materials (applied through :mod:`.scene_look`)."""

    sky_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    road_wear: float = 0.0
    road_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    wet_patch_coverage: float = 0.0
    shoulder_surface: str = "shoulder"
    verge_surface: str = "grass"
    # Potholes on real highways range from dark water-filled holes to pale exposed base course and
    # dust: a diffuse multiplier (brightness x warm tint) and the wet interior now and then, so a
    # network learns their shape and context rather than one shade.
    pothole_albedo: tuple[float, float, float] = (1.0, 1.0, 1.0)
    pothole_surface: str = "pothole"


@dataclass(frozen=True)
class ImageEffects:
    """The camera model's parameters for one frame (see :func:`apply_sensor`)."""

    exposure: float = 1.0
    wb_gains: tuple[float, float, float] = (1.0, 1.0, 1.0)
    gain: float = 0.0
    read_noise: float = 0.0
    travel_m: float = 0.0          # distance the car moves during the exposure (motion blur)
    vignetting: float = 0.0        # 0 none, 1 natural cos^4 falloff
    jpeg_quality: int = 95
    noise_seed: tuple[int, ...] = (0,)
    saturation: float = 1.0        # 1: as rendered
    blur_px: float = 0.0           # Gaussian sigma of the optics (0: none)
    target_luminance: float | None = None   # mean linear luminance the exposure aims at (None: fixed exposure)

    _IDENTITY = {"saturation": 1.0, "blur_px": 0.0, "target_luminance": None}

    def as_dict(self) -> dict:
        """The fields, less the camera-target ones at their identity (a frame record without
        targets reads as it did before they existed)."""
        return {k: v for k, v in _field_values(self).items() if not (k in self._IDENTITY and v == self._IDENTITY[k])}


@dataclass(frozen=True)
class FrameRandomization:
    index: int
    render: RenderParams
    look: SceneLook
    effects: ImageEffects

    def as_dict(self) -> dict:
        r = self.render
        return {"index": self.index, "render": {"weather": r.weather, "sun_elevation_deg": r.sun_elevation_deg,
                                                "sun_azimuth_deg": r.sun_azimuth_deg, "wetness": r.wetness,
                                                "fog_density": r.fog_density},
                "look": _field_values(self.look), "effects": self.effects.as_dict()}


def _field_values(obj) -> dict:
    """A dataclass's fields by name, shallow: its fields are numbers, strings and tuples of them,
    which ``dataclasses.asdict``'s deep copy (a third of this module's draw time) only rebuilt."""
    return {f.name: getattr(obj, f.name) for f in fields(obj)}


def draw(seed: int, index: int, base: RenderParams | None = None, ranges: Ranges = Ranges()) -> FrameRandomization:
    """Frame ``index``'s render parameters, look and image effects; depends on nothing else.
    ``base`` supplies the fields not randomized (device, backend, label distance ...)."""
    if seed < 0 or index < 0:
        raise RoadtwinError(f"randomization: seed and frame index must be >= 0, got {seed}, {index}")
    ranges.check()
    rng = np.random.default_rng([seed, index, _STREAM_DRAW])
    u = lambda lohi: float(rng.uniform(*lohi))   # noqa: E731 - one draw per call, in a fixed order
    wet = bool(rng.random() < ranges.wet_probability)
    sun_el = u(ranges.sun_elevation_deg)
    sun_az = float(rng.uniform(-180.0, 180.0))
    wetness = u(ranges.wetness) if wet else 0.0
    haze = u(ranges.haze_density)
    base = base or RenderParams()
    render = RenderParams(**{**_field_values(base), "weather": "wet" if wet else "clear", "sun_elevation_deg": sun_el,
                             "sun_azimuth_deg": sun_az, "wetness": wetness, "fog_density": None if wet else haze})
    patches = bool(rng.random() < ranges.wet_patch_probability) and not wet
    coverage = u(ranges.wet_patch_coverage)
    sky = u(ranges.sky_tint)
    road_t = u(ranges.road_tint)
    look = SceneLook(sky_tint=(1.0 - sky, 1.0 - sky / 2, 1.0 + sky), road_wear=u(ranges.road_wear),
                     road_tint=(1.0 + road_t, 1.0, 1.0 - road_t), wet_patch_coverage=coverage if patches else 0.0,
                     shoulder_surface=str(ranges.shoulder_surfaces[int(rng.integers(len(ranges.shoulder_surfaces)))]),
                     verge_surface=str(ranges.verge_surfaces[int(rng.integers(len(ranges.verge_surfaces)))]))
    # drawn from a stream of their own, so adding them left every earlier draw as it was
    extra = np.random.default_rng([seed, index, _STREAM_DRAW, 1])
    lo, hi = ranges.pothole_brightness
    bright = math.exp(extra.uniform(math.log(lo), math.log(hi)))
    warm = float(extra.uniform(*ranges.pothole_warmth))
    look = replace(look, pothole_albedo=(bright * (1 + warm), bright, bright * (1 - warm)),
                   pothole_surface="pothole_wet" if extra.random() < ranges.pothole_wet_probability else "pothole")
    temp, tint = u(ranges.wb_temperature), u(ranges.wb_tint)
    t_lo, t_hi = ranges.exposure_time_s
    t_exp = math.exp(rng.uniform(math.log(t_lo), math.log(t_hi)))
    effects = ImageEffects(exposure=2.0 ** u(ranges.exposure_ev), wb_gains=(1.0 + temp, 1.0 + tint, 1.0 - temp),
                           gain=u(ranges.gain), read_noise=u(ranges.read_noise), travel_m=u(ranges.speed_mps) * t_exp,
                           vignetting=u(ranges.vignetting),
                           jpeg_quality=int(rng.integers(ranges.jpeg_quality[0], ranges.jpeg_quality[1] + 1)),
                           noise_seed=(int(seed), int(index), _STREAM_NOISE))
    # camera targets: a stream of their own, so the draws above stay as they were
    cam = np.random.default_rng([seed, index, _STREAM_DRAW, 2])
    sat, blur = float(cam.uniform(*ranges.saturation)), float(cam.uniform(*ranges.optics_blur_px))
    target = None
    if ranges.frame_luminance is not None:
        lo, hi = ranges.frame_luminance
        target = math.exp(cam.uniform(math.log(lo), math.log(hi)))
    effects = replace(effects, saturation=sat, blur_px=blur, target_luminance=target)
    return FrameRandomization(index, render, look, effects)


# ------------------------------------------------------------------------------ camera model
def forward_flow(camera: Camera, depth: np.ndarray, travel_m: float) -> np.ndarray:
    """(H, W, 2) image motion in pixels of each pixel's world point while the camera moves
    ``travel_m`` along its horizontal heading (a car driving forward); 0 where there is no hit
    (sky: infinitely far, no parallax)."""
    k = camera.intrinsics
    depth = np.asarray(depth, dtype=np.float64)
    f = camera.rotation[:, 2]
    h = np.array([f[0], f[1], 0.0])
    h /= max(float(np.linalg.norm(h)), 1e-12)
    t_cam = camera.rotation.T @ (travel_m * h)               # camera displacement in camera axes
    u, v, xn, yn = pixel_grid(k)
    ok = np.isfinite(depth) & (depth > 0)
    z = np.where(ok, depth, 1.0)
    x, y = xn * z, yn * z
    z2 = np.maximum(z - t_cam[2], 1e-3)
    u2 = k.fx * (x - t_cam[0]) / z2 + k.cx
    v2 = k.fy * (y - t_cam[1]) / z2 + k.cy
    return np.where(ok[..., None], np.stack([u2 - u, v2 - v], axis=-1), 0.0).astype(np.float32)


def motion_blur(rgb: np.ndarray, flow: np.ndarray, max_taps: int = 25) -> np.ndarray:
    """Average of the image sampled along each pixel's flow over the exposure (centred): the
    blur a moving camera integrates; a pixel with no flow stays sharp."""
    import cv2

    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    flow = np.asarray(flow, dtype=np.float32)
    longest = float(np.abs(flow).max()) if flow.size else 0.0
    if longest < 0.25:
        return rgb.copy()
    taps = int(min(max_taps, math.ceil(longest) + 1))
    h, w = rgb.shape[:2]
    gx, gy = _grid32(w, h)
    acc = np.zeros_like(rgb)
    for t in np.linspace(-0.5, 0.5, taps, dtype=np.float32):
        acc += cv2.remap(rgb, gx + t * flow[..., 0], gy + t * flow[..., 1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT)
    return acc / taps


@functools.lru_cache(maxsize=4)
def _grid32(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Read-only float32 pixel column and row grids (cached: every frame asks)."""
    gx, gy = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    gx.flags.writeable = gy.flags.writeable = False
    return gx, gy


def vignetting(camera_or_size, strength: float) -> np.ndarray:
    """(H, W) relative illumination cos(theta)^(4 * strength), theta the angle off the optical
    axis: 1 at the principal point, falling monotonically towards the corners."""
    k = camera_or_size.intrinsics if isinstance(camera_or_size, Camera) else camera_or_size
    _, _, xn, yn = pixel_grid(k)
    r2 = xn ** 2 + yn ** 2                                         # tan^2(theta)
    return (1.0 / (1.0 + r2)) ** (2.0 * strength)                  # cos^2 = 1 / (1 + tan^2)


def sensor_noise(linear: np.ndarray, gain: float, read_noise: float, rng: np.random.Generator) -> np.ndarray:
    """Photon noise (Poisson counts of ``signal / gain`` electrons, times ``gain``) plus
    Gaussian read noise: variance = gain * signal + read_noise^2."""
    x = np.maximum(np.asarray(linear, dtype=np.float64), 0.0)
    if gain > 0:
        x = rng.poisson(x / gain) * gain
    if read_noise > 0:
        x = x + rng.normal(0.0, read_noise, size=x.shape)
    return x.astype(np.float32)


def encode_jpeg(image8: np.ndarray, quality: int) -> bytes:
    """JPEG bytes (Pillow, baseline, 4:2:0, no optimisation: same input, same bytes)."""
    if not 1 <= int(quality) <= 100:
        raise RoadtwinError(f"JPEG quality must be in 1..100, got {quality}")
    buf = io.BytesIO()
    Image.fromarray(np.asarray(image8, dtype=np.uint8)).save(buf, format="JPEG", quality=int(quality), subsampling=2,
                                                             optimize=False)
    return buf.getvalue()


def decode_jpeg(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def auto_exposure(linear: np.ndarray, target: float) -> float:
    """The scale ``k`` for which the frame's mean *displayed* linear luminance, after the tone
    curve ``1 - exp(-k L)`` (:func:`~roadtwin_core.render.tonemap.to_srgb8`), equals ``target``
    (what ``bench/camera_stats.py`` measures on real frames: sRGB decoded to linear). Bisection
    in log k on every 4th pixel of every 4th row."""
    if not 0.0 < target < 1.0:
        raise RoadtwinError(f"auto-exposure target must be in (0, 1), got {target}")
    c = np.maximum(np.asarray(linear, np.float64)[::4, ::4].reshape(-1, 3), 0.0)   # per channel, as displayed
    if not c.size or c.max() <= 0:
        return 1.0
    w = np.asarray(_LUMA)
    lo, hi = math.log(1e-4), math.log(1e4)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if float((-np.expm1(-math.exp(mid) * c) @ w).mean()) < target else (lo, mid)
    return math.exp(0.5 * (lo + hi))


def apply_sensor(rgb: np.ndarray, effects: ImageEffects, camera: Camera | None = None,
                 depth: np.ndarray | None = None) -> tuple[np.ndarray, bytes]:
    """Rendered linear RGB (H, W, 3) -> what the camera records: (8-bit sRGB as decoded from the
    JPEG, the JPEG bytes). Motion blur needs the camera and depth (without them none is
    applied); vignetting needs the camera (the field of view sets the falloff)."""
    x = np.asarray(rgb, dtype=np.float32)
    if x.ndim != 3 or x.shape[2] != 3:
        raise RoadtwinError(f"sensor model: expected an (H, W, 3) linear RGB image, got shape {x.shape}")
    if camera is not None and depth is not None and effects.travel_m > 0:
        x = motion_blur(x, forward_flow(camera, depth, effects.travel_m))
    if effects.blur_px > 0:
        import cv2

        x = cv2.GaussianBlur(np.ascontiguousarray(x), (0, 0), float(effects.blur_px), borderType=cv2.BORDER_REFLECT)
    if camera is not None and effects.vignetting > 0:
        x = x * vignetting(camera, effects.vignetting)[..., None].astype(np.float32)
    if effects.target_luminance is not None:     # auto-exposure: the frame's mean luminance hits the target
        x = x * np.float32(auto_exposure(x, effects.target_luminance))
    x = x * np.float32(effects.exposure)
    x = sensor_noise(x, effects.gain, effects.read_noise, np.random.default_rng(list(effects.noise_seed)))
    x = x * np.asarray(effects.wb_gains, dtype=np.float32)
    if effects.saturation != 1.0:
        y = (x @ np.asarray(_LUMA, np.float32))[..., None]
        x = y + np.float32(effects.saturation) * (x - y)
    data = encode_jpeg(to_srgb8(x), effects.jpeg_quality)
    return decode_jpeg(data), data
