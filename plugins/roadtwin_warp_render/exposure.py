"""A drive camera's exposure developed where the frame is rendered: motion blur by reprojection,
the tone curve and read noise as one warp kernel (``WarpRenderer.render_exposed``).

Why: a drive's stereo pair at 1280x720 spent most of its time after the render, on the host: the
G-buffers' copy (~37 MB an eye), the blur's sub-frames and the read noise drawn on one core. Here
the same model as ``roadtwin_sensors.camera`` (``reproject_blur`` then ``CameraSensor._develop``)
runs beside the G-buffer and only the 8-bit image (and the left eye's labels) travel.

The model, pixel by pixel: the middle sub-frame's z-depth (sky: ``far_m``) puts pixel q of each
sub-frame camera on a point, which ``rel`` (middle camera <- sub-frame camera) takes to the
middle frame, where the shaded image is sampled bilinearly with the border replicated (an
unmoved sub-frame takes the pixel itself); the sub-frames' mean goes through the tone curve and
sRGB to 8 bit, then read noise (DN) from warp's counter-based generator keyed by (seed, pixel,
channel), rounded and clipped. cv2.remap, on the host, samples at 1/32 pixel: the images differ
by rounding (tests bound it); the noise is other random numbers than numpy's (same seed, same
device: same bytes).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from .post_kernels import srgb8
from .raycast import Cam

__all__ = ["develop_exposure", "relative_poses"]

wp.set_module_options({"enable_backward": False})


@wp.func
def replicate_bilinear(img: wp.array(dtype=wp.vec3), w: int, h: int, x: float, y: float) -> wp.vec3:
    """Bilinear sample at (x, y), indices clamped to the image (cv2.BORDER_REPLICATE)."""
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    fx = x - x0
    fy = y - y0
    i0 = wp.clamp(int(x0), 0, w - 1)
    i1 = wp.clamp(int(x0) + 1, 0, w - 1)
    j0 = wp.clamp(int(y0), 0, h - 1)
    j1 = wp.clamp(int(y0) + 1, 0, h - 1)
    top = img[j0 * w + i0] * (1.0 - fx) + img[j0 * w + i1] * fx
    bot = img[j1 * w + i0] * (1.0 - fx) + img[j1 * w + i1] * fx
    return top * (1.0 - fy) + bot * fy


@wp.kernel
def exposure_kernel(rgb: wp.array(dtype=wp.vec3), depth: wp.array(dtype=float), cam: Cam,
                    rel: wp.array(dtype=wp.mat44), moved: wp.array(dtype=wp.int32), n_sub: int, far_m: float,
                    read_noise: float, seed: int, out: wp.array(dtype=wp.uint8)):
    tid = wp.tid()
    w = cam.width
    h = cam.height
    i = tid % w
    j = tid // w
    z = depth[tid]
    if not (z > 0.0 and z < 1.0e30):
        z = far_m
    p = wp.vec4((float(i) - cam.cx) / cam.fx * z, (float(j) - cam.cy) / cam.fy * z, z, 1.0)
    acc = wp.vec3(0.0, 0.0, 0.0)
    for s in range(n_sub):
        c = rgb[tid]
        if moved[s] != 0:
            q = rel[s] * p
            u = float(-1.0)
            v = float(-1.0)
            if q[2] > 1.0e-6:
                u = cam.fx * q[0] / q[2] + cam.cx
                v = cam.fy * q[1] / q[2] + cam.cy
            c = replicate_bilinear(rgb, w, h, u, v)
        acc = acc + c
    acc = acc / float(n_sub)
    state = wp.rand_init(seed, 3 * tid)
    for k in range(3):
        dn = float(srgb8(acc[k]))
        if read_noise > 0.0:
            dn = dn + wp.randn(state) * read_noise
        out[3 * tid + k] = wp.uint8(int(wp.clamp(wp.round(dn), 0.0, 255.0)))


def relative_poses(mid_cam_to_world: np.ndarray, cams_to_world: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(middle camera <- each sub-frame camera, as float32 4x4s; whether each moved at all)."""
    inv = np.linalg.inv(mid_cam_to_world)
    rel = np.stack([(inv @ m).astype(np.float32) for m in cams_to_world])
    moved = np.array([not np.array_equal(m, mid_cam_to_world) for m in cams_to_world], np.int32)
    return rel, moved


def develop_exposure(gb, cam: Cam, mid_cam_to_world: np.ndarray, cams_to_world: list[np.ndarray], far_m: float,
                     read_noise: float, seed: int) -> np.ndarray:
    """8-bit RGB (H, W, 3) of the exposure, developed on the G-buffer ``gb``'s device and copied to the host."""
    rel, moved = relative_poses(mid_cam_to_world, cams_to_world)
    dev = gb.rgb.device
    out = wp.empty(cam.width * cam.height * 3, dtype=wp.uint8, device=dev)
    wp.launch(exposure_kernel, dim=cam.width * cam.height, device=dev,
              inputs=[gb.rgb, gb.depth, cam, wp.array(rel, dtype=wp.mat44, device=dev),
                      wp.array(moved, dtype=wp.int32, device=dev), len(cams_to_world), float(far_m),
                      float(read_noise), int(seed) & 0x7FFFFFFF],
              outputs=[out])
    return out.numpy().reshape(cam.height, cam.width, 3)
