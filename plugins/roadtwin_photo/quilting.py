"""Image quilting on a torus: a texture that wraps without a seam and without a short period,
made of patches of several photographed windows (core-free: numpy, OpenCV, scipy.ndimage).

A window of clean road is about 2 m a side, the material repeats every ``ST_TILE_M`` (4 m):
repeating the window 2 x 2 puts every stain, wheel path and light change of it back every 2 m,
a band across the lane at that period that no real road has. Efros & Freeman (2001, "Image
quilting for texture synthesis and transfer", SIGGRAPH) make a larger texture from an
exemplar instead: square blocks laid on a grid with a band of overlap, each block the one of
the sources (within ``tolerance`` of the smallest error, picked at random) whose pixels in the
overlap agree best with what is already laid (sum of squared differences over the filled
pixels, ``cv2.matchTemplate`` with a mask), and the border between old and new run along the
*minimum-error boundary cut* (dynamic programming through the overlap's squared difference),
so it follows the asphalt's own grain instead of a straight line.

Here the grid wraps (toroidal quilting): the last block of a row overlaps the first one, the
last row the first row, and their overlaps are cut the same way, so the texture's right edge is
followed by its left edge as any block by its neighbour: the wrap is no seam. The cut is
feathered over a texel or two (a hard cut between two photos shows as a one-texel step).
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

FEATHER_TEXELS = 1.0


def block_grid(size: int, block_texels: float) -> tuple[np.ndarray, int]:
    """Block origins along one axis (``G`` of them, G >= 2, spaced ``size / G`` rounded down)
    and the block side: the spacing plus a sixth of it, the overlap Efros & Freeman use."""
    count = max(2, int(round(size / max(block_texels, 4.0))))
    origins = (np.arange(count) * size) // count
    step = int(np.diff(np.append(origins, size)).max())
    return origins, step + max(2, step // 6)


def fitting_block(size: int, block_texels: float, smallest: int) -> float:
    """``block_texels``, or less where its block (with overlap) would not fit a source of
    ``smallest`` texels a side."""
    while block_texels > 4.0 and block_grid(size, block_texels)[1] > smallest:
        block_texels *= 0.9
    return block_texels


def min_cut_path(error: np.ndarray) -> np.ndarray:
    """For each row of ``error`` (rows, width), the column of the connected top-to-bottom path
    (steps of at most one column per row) of the least summed error."""
    rows, width = error.shape
    cost = error.astype(np.float64).copy()
    for r in range(1, rows):
        prev = cost[r - 1]
        left = np.concatenate([[np.inf], prev[:-1]])
        right = np.concatenate([prev[1:], [np.inf]])
        cost[r] += np.minimum(prev, np.minimum(left, right))
    path = np.empty(rows, np.int64)
    path[-1] = int(np.argmin(cost[-1]))
    for r in range(rows - 2, -1, -1):
        c = path[r + 1]
        lo, hi = max(0, c - 1), min(width, c + 2)
        path[r] = lo + int(np.argmin(cost[r, lo:hi]))
    return path


def _band_widths(filled: np.ndarray) -> tuple[int, int, int, int]:
    """Filled columns at the block's left and right, rows at its top and bottom (overlaps are
    under half a block, so the middle row and column cross only the side bands)."""
    mid_row, mid_col = filled[filled.shape[0] // 2], filled[:, filled.shape[1] // 2]

    def run(v: np.ndarray) -> int:
        return int(np.argmin(v)) if not v.all() else len(v)

    return run(mid_row), run(mid_row[::-1]), run(mid_col), run(mid_col[::-1])


def cut_mask(patch: np.ndarray, old: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """1 where the new block's texel is kept, 0 where the old one stays: beyond the minimum-error
    cut of every side band that is already filled; 1 wherever nothing was laid yet."""
    err = ((patch - old) ** 2).sum(axis=-1)
    b = patch.shape[0]
    new = np.ones((b, b), bool)
    left, right, top, bottom = _band_widths(filled)
    rows = np.arange(b)
    if left:
        cut = min_cut_path(err[:, :left])
        new[np.arange(b)[None, :] < cut[:, None]] = False
    if right:
        cut = b - right + min_cut_path(err[:, b - right:])
        new[np.arange(b)[None, :] > cut[:, None]] = False
    if top:
        cut = min_cut_path(err[:top].T)
        new[rows[:, None] < cut[None, :]] = False
    if bottom:
        cut = b - bottom + min_cut_path(err[b - bottom:].T)
        new[rows[:, None] > cut[None, :]] = False
    return new | ~filled


class _Matcher:
    """Masked sum of squared differences of a laid block against every block of the sources,
    at half resolution for big blocks (the choice is among near-equals anyway), with the
    positions near blocks already used left out while others remain: a stain taken twice in
    one tile repeats within it."""

    def __init__(self, sources: list[np.ndarray], block: int, rng: np.random.Generator, tolerance: float):
        import cv2

        self.scale = 2 if block >= 48 else 1
        self.small = [s if self.scale == 1 else cv2.resize(s, (s.shape[1] // 2, s.shape[0] // 2),
                                                           interpolation=cv2.INTER_AREA) for s in sources]
        self.sources, self.block, self.rng, self.tolerance = sources, block, rng, tolerance
        self.used = [np.zeros((s.shape[0] - block + 1, s.shape[1] - block + 1), bool) for s in sources]

    def best(self, old: np.ndarray, filled: np.ndarray) -> tuple[int, int, int]:
        """(source, row, col) within ``tolerance`` of the least error, at random among those."""
        import cv2

        b = self.block
        if not filled.any():
            i = int(self.rng.integers(len(self.sources)))
            return self._take(i, int(self.rng.integers(self.used[i].shape[0])),
                              int(self.rng.integers(self.used[i].shape[1])))
        if self.scale == 2:
            old = cv2.resize(old, (b // 2, b // 2), interpolation=cv2.INTER_AREA)
            filled = cv2.resize(filled.astype(np.float32), (b // 2, b // 2), interpolation=cv2.INTER_AREA) > 0.999
        mask = np.repeat(filled[..., None], old.shape[2], axis=2).astype(np.float32)
        errors = []
        for s, used in zip(self.small, self.used):
            e = cv2.matchTemplate(s, old.astype(np.float32), cv2.TM_SQDIFF, mask=mask)
            e = np.repeat(np.repeat(e, self.scale, 0), self.scale, 1)[:used.shape[0], :used.shape[1]]
            errors.append(np.pad(e, ((0, used.shape[0] - e.shape[0]), (0, used.shape[1] - e.shape[1])), mode="edge"))
        if not all(u.all() for u in self.used):
            errors = [np.where(u, np.inf, e) for e, u in zip(errors, self.used)]
        least = min(float(e.min()) for e in errors)
        limit = max(least, 0.0) * (1 + self.tolerance) + 1e-6
        picks = [(i, r, c) for i, e in enumerate(errors) for r, c in zip(*np.nonzero(e <= limit))]
        return self._take(*picks[int(self.rng.integers(len(picks)))])

    def _take(self, i: int, r: int, c: int) -> tuple[int, int, int]:
        near = self.block // 3
        self.used[i][max(0, r - near):r + near + 1, max(0, c - near):c + near + 1] = True
        return i, r, c


def quilt_torus(sources: list[np.ndarray], size: int, block_texels: float, rng: np.random.Generator,
                tolerance: float = 0.1) -> np.ndarray:
    """(size, size, C) float32 texture that wraps both ways, quilted from ``sources`` (float
    (h, w, C) images, each at least a block a side, on one texel and colour footing)."""
    origins, b = block_grid(size, block_texels)
    srcs = [np.ascontiguousarray(s, dtype=np.float32) for s in sources]
    if any(min(s.shape[:2]) < b for s in srcs):
        raise ValueError(f"quilt_torus: every source must be at least {b} texels a side")
    out = np.zeros((size, size, srcs[0].shape[2]), np.float32)
    filled = np.zeros((size, size), bool)
    matcher = _Matcher(srcs, b, rng, tolerance)
    for r0 in origins:
        for c0 in origins:
            rows, cols = (r0 + np.arange(b)) % size, (c0 + np.arange(b)) % size
            here = np.ix_(rows, cols)
            old, was = out[here], filled[here]
            i, r, c = matcher.best(old, was)
            patch = srcs[i][r:r + b, c:c + b]
            keep = cut_mask(patch, old, was).astype(np.float32)
            alpha = np.where(was, gaussian_filter(keep, FEATHER_TEXELS), 1.0)[..., None]
            out[here] = alpha * patch + (1 - alpha) * old
            filled[here] = True
    return out
