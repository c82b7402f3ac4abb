"""Surface models: the real-world elevation that road and defect vertices are restored onto.

A surface model answers ``height(xy) -> z``. Three sources:

* :class:`FlatSurface` — constant height.
* :class:`SampledSurface` — scattered elevation samples (terrain, LiDAR-derived meshes),
  queried through a scipy ``cKDTree``: the k nearest samples get a weighted local plane fit,
  which reproduces planes exactly and does not flatten slopes the way plain IDW does.
* :class:`GridSurface` — a regular height grid (ISO 8608 roughness), bilinear on the grid.
  A k-d tree is unnecessary on a regular grid; bilinear is exact for the grid's own
  piecewise-linear interpretation.

:class:`SumSurface` adds them (terrain + roughness). :func:`iso8608_surface` generates an
isotropic random road of an ISO 8608 class whose 1D profiles in any direction have the
displacement PSD Gd(n) = Gd(n0) (n / n0)^-2 (w = 2, n0 = 0.1 cycles/m).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom
from scipy.spatial import cKDTree

from .errors import RoadtwinError
from .plugins import get_plugin_manager
from .usd.stage import read_mesh

# ISO 8608 class geometric means Gd(n0), m^3, n0 = 0.1 cycles/m, w = 2.
ISO8608_GD_N0 = {c: 16e-6 * 4**i for i, c in enumerate("ABCDEFGH")}
ISO8608_N0 = 0.1
ISO8608_BAND = (0.011, 2.83)  # cycles/m, the standard's spatial frequency range


class SurfaceModel:
    """Base class: ``height(xy)`` for an (N,2) array of world XY in meters."""

    name = "surface"

    def height(self, xy: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError


@dataclass
class FlatSurface(SurfaceModel):
    z0: float = 0.0
    name: str = "flat"

    def height(self, xy: np.ndarray) -> np.ndarray:
        return np.full(len(np.atleast_2d(xy)), self.z0, dtype=np.float64)


class SampledSurface(SurfaceModel):
    """Elevation from scattered (N,3) samples via a k-d tree and a local plane fit."""

    name = "sampled"

    def __init__(self, points: np.ndarray, k: int = 8) -> None:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(pts) < 3 or not np.isfinite(pts).all():
            raise RoadtwinError("elevation samples: need at least 3 finite (x, y, z) points")
        self.points = pts
        self.k = min(k, len(pts))
        self.tree = cKDTree(pts[:, :2])
        # Level samples (a flat town's terrain: CARLA, OpenDRIVE without elevation) fit the
        # plane z = level everywhere; answering that directly skips the k-d tree and the 3x3
        # solves (~1 s on Town01) and is exact where the fit would round.
        self.level = float(pts[0, 2]) if (pts[:, 2] == pts[0, 2]).all() else None

    def height(self, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        if self.level is not None:
            return np.full(len(xy), self.level)
        dist, idx = self.tree.query(xy, k=self.k)
        nb = self.points[idx]  # (Q,k,3)
        w = 1.0 / np.maximum(dist, 1e-9) ** 2
        dx = nb[..., 0] - xy[:, None, 0]
        dy = nb[..., 1] - xy[:, None, 1]
        a = np.stack([np.ones_like(dx), dx, dy], axis=-1)  # plane z = c0 + c1 dx + c2 dy
        ata = np.einsum("qk,qki,qkj->qij", w, a, a)
        atb = np.einsum("qk,qki,qk->qi", w, a, nb[..., 2])
        idw = (w * nb[..., 2]).sum(1) / w.sum(1)
        det = np.linalg.det(ata)
        ok = np.abs(det) > 1e-12 * np.maximum(1.0, np.abs(ata).max(axis=(1, 2))) ** 3
        z = idw.copy()
        if ok.any():
            z[ok] = np.linalg.solve(ata[ok], atb[ok][..., None])[:, 0, 0]
        exact = dist[:, 0] < 1e-12
        z[exact] = nb[exact, 0, 2]
        return z


class GridSurface(SurfaceModel):
    """Heights on a regular grid: ``heights[i, j]`` at (x0 + j*dx, y0 + i*dx); bilinear."""

    name = "grid"

    def __init__(self, x0: float, y0: float, dx: float, heights: np.ndarray) -> None:
        self.x0, self.y0, self.dx = float(x0), float(y0), float(dx)
        self.heights = np.asarray(heights, dtype=np.float64)

    def height(self, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        ny, nx = self.heights.shape
        fx = np.clip((xy[:, 0] - self.x0) / self.dx, 0, nx - 1 - 1e-9)
        fy = np.clip((xy[:, 1] - self.y0) / self.dx, 0, ny - 1 - 1e-9)
        j, i = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
        tx, ty = fx - j, fy - i
        h = self.heights
        return ((1 - tx) * (1 - ty) * h[i, j] + tx * (1 - ty) * h[i, j + 1]
                + (1 - tx) * ty * h[i + 1, j] + tx * ty * h[i + 1, j + 1])


class SumSurface(SurfaceModel):
    name = "sum"

    def __init__(self, *parts: SurfaceModel) -> None:
        self.parts = parts

    def height(self, xy: np.ndarray) -> np.ndarray:
        return sum(p.height(xy) for p in self.parts)


def iso8608_psd_2d(n: np.ndarray, road_class: str) -> np.ndarray:
    """Two-sided isotropic 2D PSD whose 1D one-sided marginal is Gd(n0)(n/n0)^-2.

    For S2(|n|) = A |n|^-3 the marginal is S1(n1) = 2A / n1^2; with Gd = 2 S1 this gives
    A = Gd(n0) n0^2 / 4.
    """
    gd = ISO8608_GD_N0[road_class]
    with np.errstate(divide="ignore"):
        return gd * ISO8608_N0**2 / (4.0 * np.abs(n) ** 3)


def _cell_average_low(s2: np.ndarray, n1: np.ndarray, n2: np.ndarray, dn1: float, dn2: float,
                      band: tuple[float, float], road_class: str, radius: int = 8,
                      sub: int = 8) -> np.ndarray:
    """Replace the PSD at the lattice points nearest the origin by its mean over the cell.

    Near the origin S2 ~ |n|^-3 changes by orders of magnitude across one frequency cell and
    the band's lower edge cuts through cells, so point sampling misstates the low-frequency
    energy, which dominates the height variance: with an FFT just long enough to reach
    ``band[0]`` (dn slightly below band[0], so the on-axis modes fall outside the band) the
    field had about 20 % less variance than the band integral. Cell means over a
    ``sub`` x ``sub`` sub-grid make the synthesised variance match
    ``integral of S2 over the band`` to within a few per cent whatever the FFT size. The
    sub-grid is symmetric, so the spectrum stays Hermitian; the DC cell lies inside
    |n| < band[0] and stays zero.
    """
    rx = min(radius, len(n1) - 2)
    ry = min(radius, len(n2) // 2 - 1)
    if rx < 0 or ry < 0:
        return s2
    kx = np.arange(0, rx + 1)  # half spectrum (rfft): non-negative n1 only
    ky = np.arange(-ry, ry + 1)
    off = (np.arange(sub) + 0.5) / sub - 0.5
    fx = (kx[:, None] + off[None, :]) * dn1  # (kx, sub)
    fy = (ky[:, None] + off[None, :]) * dn2  # (ky, sub)
    r = np.hypot(fx[None, :, None, :], fy[:, None, :, None])  # (ky, kx, sub_y, sub_x)
    inside = (r >= band[0]) & (r <= band[1])
    with np.errstate(divide="ignore"):
        vals = np.where(inside, iso8608_psd_2d(r, road_class), 0.0)
    out = s2.copy()
    out[np.ix_(ky % len(n2), kx % len(n1))] = vals.mean(axis=(2, 3))
    return out


def iso8608_surface(road_class: str, bounds: tuple[float, float, float, float], seed: int,
                    dx: float = 0.1, band: tuple[float, float] = ISO8608_BAND) -> GridSurface:
    """A seeded ISO 8608 random road covering ``bounds`` (xmin, ymin, xmax, ymax), FFT-synthesised."""
    road_class = road_class.upper()
    if road_class not in ISO8608_GD_N0:
        raise RoadtwinError(f"surface: unknown ISO 8608 class {road_class!r} (use A..H)")
    if not (math.isfinite(dx) and dx > 0):
        raise RoadtwinError(f"surface: grid spacing must be positive, got {dx}")
    xmin, ymin, xmax, ymax = bounds
    nx = int(math.ceil((xmax - xmin) / dx)) + 2
    ny = int(math.ceil((ymax - ymin) / dx)) + 2
    # FFT size: even, and long enough that the lowest band frequency is resolved.
    n_fft_x = max(nx, int(math.ceil(1.0 / (band[0] * dx))))
    n_fft_y = max(ny, int(math.ceil(1.0 / (band[0] * dx))))
    n_fft_x += n_fft_x % 2
    n_fft_y += n_fft_y % 2
    if n_fft_x * n_fft_y > 120_000_000:
        raise RoadtwinError(f"surface: ISO 8608 grid of {n_fft_x}x{n_fft_y} cells is too large; raise the spacing")
    rng = np.random.default_rng(seed)
    # Real FFTs: the field is real, so only the half spectrum n1 >= 0 is stored (half the memory).
    spectrum = np.fft.rfft2(rng.standard_normal((n_fft_y, n_fft_x)))
    n1 = np.fft.rfftfreq(n_fft_x, d=dx)
    n2 = np.fft.fftfreq(n_fft_y, d=dx)
    nr = np.hypot(n1[None, :], n2[:, None])
    s2 = np.where((nr >= band[0]) & (nr <= band[1]), iso8608_psd_2d(nr, road_class), 0.0)
    del nr
    dn1, dn2 = 1.0 / (n_fft_x * dx), 1.0 / (n_fft_y * dx)
    s2 = _cell_average_low(s2, n1, n2, dn1, dn2, band, road_class)
    spectrum *= np.sqrt(s2 * dn1 * dn2 * n_fft_x * n_fft_y)
    del s2
    field = np.fft.irfft2(spectrum, s=(n_fft_y, n_fft_x))[:ny, :nx].copy()
    return GridSurface(xmin - dx / 2, ymin - dx / 2, dx, field)


def parse_surface(spec: str, bounds: tuple[float, float, float, float], seed: int,
                  terrain: np.ndarray | None = None) -> SurfaceModel:
    """``flat``, ``flat:Z``, ``iso8608:C[:DX]``, ``usd:SURFACE.usda`` (a surface asset's mesh
    vertices, through the k-d tree) or a plugin's ``SCHEME:ARG``; adds the layout's terrain if any."""
    spec = spec.strip()
    kind, _, arg = spec.partition(":")
    kind = kind.lower()
    parts = spec.split(":")
    base: SurfaceModel | None = SampledSurface(terrain) if terrain is not None and len(terrain) else None
    try:
        if kind == "flat":
            rough: SurfaceModel = FlatSurface(float(parts[1]) if len(parts) > 1 else 0.0)
        elif kind == "iso8608":
            if len(parts) < 2:
                raise RoadtwinError("surface: iso8608 needs a class, e.g. iso8608:C")
            dx = float(parts[2]) if len(parts) > 2 else 0.1
            rough = iso8608_surface(parts[1], bounds, seed, dx=dx)
        elif kind == "usd":
            rough = usd_mesh_surface(arg)
        else:
            sources = get_plugin_manager().registry("surface_sources")
            if kind not in sources:
                known = ", ".join(["flat, flat:Z, iso8608:CLASS[:DX], usd:PATH"] + [f"{k}:ARG" for k in sorted(sources)])
                raise RoadtwinError(f"surface: unknown source {spec!r} (use {known})")
            rough = sources[kind].load(arg, bounds, seed)
    except ValueError:
        raise RoadtwinError(f"surface: cannot parse {spec!r}") from None
    return rough if base is None else SumSurface(base, rough)


def usd_mesh_surface(path: str) -> SampledSurface:
    """Elevation from a surface asset (e.g. ``roadtwin reconstruct surface`` output): the
    world-space vertices of its meshes, queried through the k-d tree."""
    p = Path(path)
    if not p.exists():
        raise RoadtwinError(f"surface: {path}: no such file")
    stage = Usd.Stage.Open(str(p))
    pts = [read_mesh(UsdGeom.Mesh(prim))[0] for prim in stage.Traverse() if prim.IsA(UsdGeom.Mesh)]
    if not pts:
        raise RoadtwinError(f"surface: {path}: has no mesh")
    return SampledSurface(np.concatenate(pts))
