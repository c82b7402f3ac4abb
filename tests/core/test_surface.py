"""Surface models checked against independent references.

ISO 8608 roughness is checked with an estimator written here (Hann-windowed one-sided
periodogram of rows and columns, averaged over rows and seeds, then a least-squares line in
log-log), not with anything from ``roadtwin_core.surface``. The class table below is typed in
from ISO 8608 (Gd(n0) in 1e-6 m^3, n0 = 0.1 cycles/m, w = 2) rather than imported.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from roadtwin_core import (FlatSurface, GridSurface, RoadtwinError, SampledSurface, SumSurface,
                           iso8608_surface, parse_surface)
from roadtwin_core.surface import ISO8608_BAND, ISO8608_GD_N0

N0 = 0.1  # cycles/m
ISO_CLASSES = {"A": 16e-6, "B": 64e-6, "C": 256e-6, "D": 1024e-6, "E": 4096e-6,
               "F": 16384e-6, "G": 65536e-6, "H": 262144e-6}
FIT_BAND = (0.05, 1.0)  # cycles/m, well inside the synthesised band (0.011 .. 2.83)


# --------------------------------------------------------------------------- estimators
def one_sided_psd(profiles: np.ndarray, dx: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean one-sided displacement PSD (m^3) of the rows of ``profiles`` (Hann window).

    For a record of N samples the periodogram 2 |FFT(w x)|^2 dx / sum(w^2) is an unbiased
    (up to window leakage) estimate of the one-sided PSD Gd(n) at n = k / (N dx).
    """
    n = profiles.shape[1]
    win = np.hanning(n)
    x = profiles - profiles.mean(axis=1, keepdims=True)
    spec = np.fft.rfft(x * win, axis=1)
    psd = 2.0 * np.abs(spec) ** 2 * dx / (win**2).sum()
    return np.fft.rfftfreq(n, dx), psd.mean(axis=0)


def fit_gd(freq: np.ndarray, psd: np.ndarray) -> tuple[float, float]:
    """Least squares of log Gd = log Gd(n0) - w log(n/n0) over FIT_BAND -> (Gd(n0), w)."""
    m = (freq >= FIT_BAND[0]) & (freq <= FIT_BAND[1])
    slope, intercept = np.polyfit(np.log(freq[m] / N0), np.log(psd[m]), 1)
    return math.exp(intercept), -slope


def iso_class_of(gd_n0: float) -> str:
    """ISO 8608 rule: class limits are geometric, mean/2 .. 2*mean (A starts at 0)."""
    for cls, mean in ISO_CLASSES.items():
        lower = 0.0 if cls == "A" else mean / 2
        if lower <= gd_n0 < 2 * mean:
            return cls
    return "H+"


def measured(cls: str, seeds=range(3), size: float = 51.2, dx: float = 0.1):
    """Fitted (Gd(n0), w) along x (rows) and along y (columns), averaged over seeds."""
    px, py = [], []
    for seed in seeds:
        h = iso8608_surface(cls, (0.0, 0.0, size, size), seed, dx=dx).heights
        freq, p = one_sided_psd(h, dx)
        px.append(p)
        py.append(one_sided_psd(h.T, dx)[1])
    return fit_gd(freq, np.mean(px, axis=0)), fit_gd(freq, np.mean(py, axis=0))


# --------------------------------------------------------------------------- ISO 8608
def test_class_table_matches_the_standard():
    assert ISO8608_GD_N0 == pytest.approx(ISO_CLASSES, rel=1e-12)
    assert ISO8608_BAND[0] <= 0.011 and ISO8608_BAND[1] >= 2.83


@pytest.fixture(scope="module")
def fits():
    # different seeds per class: with equal seeds the classes are the same field, scaled
    return {cls: measured(cls, seeds=range(10 * i, 10 * i + 3)) for i, cls in enumerate("ACE")}


@pytest.mark.parametrize("cls", list("ACE"))
def test_iso8608_psd_level_slope_and_class(fits, cls):
    (gd_x, w_x), (gd_y, w_y) = fits[cls]
    gd = math.sqrt(gd_x * gd_y)
    assert gd == pytest.approx(ISO_CLASSES[cls], rel=0.25), (gd, ISO_CLASSES[cls])
    assert w_x == pytest.approx(2.0, abs=0.2)
    assert w_y == pytest.approx(2.0, abs=0.2)
    assert iso_class_of(gd) == cls
    assert iso_class_of(gd_x) == cls and iso_class_of(gd_y) == cls


@pytest.mark.parametrize("cls", list("ACE"))
def test_iso8608_isotropic(fits, cls):
    (gd_x, w_x), (gd_y, w_y) = fits[cls]
    assert gd_x == pytest.approx(gd_y, rel=0.2)
    assert w_x == pytest.approx(w_y, rel=0.2)


def test_iso8608_isotropic_slope_statistics():
    # RMS height difference over 1 m lag along x and along y (a different statistic than the
    # PSD fit above) agree.
    dx, lag = 0.1, 10
    dzx, dzy = [], []
    for seed in range(3):
        h = iso8608_surface("C", (0, 0, 40, 40), seed, dx=dx).heights
        dzx.append(np.mean((h[:, lag:] - h[:, :-lag]) ** 2))
        dzy.append(np.mean((h[lag:, :] - h[:-lag, :]) ** 2))
    assert np.mean(dzx) == pytest.approx(np.mean(dzy), rel=0.2)


def test_iso8608_seeded():
    b = (0.0, 0.0, 12.0, 7.0)
    a1 = iso8608_surface("C", b, 7).heights
    a2 = iso8608_surface("C", b, 7).heights
    a3 = iso8608_surface("C", b, 8).heights
    assert np.array_equal(a1, a2)
    assert a1.shape == a3.shape
    assert not np.allclose(a1, a3)
    # The same random field scaled by sqrt(Gd ratio) between classes (same seed).
    e = iso8608_surface("E", b, 7).heights
    np.testing.assert_allclose(e, a1 * math.sqrt(ISO_CLASSES["E"] / ISO_CLASSES["C"]), rtol=1e-9,
                               atol=1e-15)


def test_iso8608_grid_covers_bounds():
    b = (-3.0, 10.0, 17.3, 14.2)
    g = iso8608_surface("B", b, 1, dx=0.1)
    ny, nx = g.heights.shape
    assert g.x0 <= b[0] and g.y0 <= b[1]
    assert g.x0 + (nx - 1) * g.dx >= b[2] and g.y0 + (ny - 1) * g.dx >= b[3]
    assert np.isfinite(g.heights).all()


def test_iso8608_variance_matches_band_integral():
    """Point variance vs the integral of the PSD over the synthesised band.

    The generator makes an isotropic 2D field with S2(n) = A |n|^-3 on the annulus
    n_lo <= |n| <= n_hi, A = Gd(n0) n0^2 / 4 (so that every 1D profile has one-sided
    Gd(n) = Gd(n0) (n0/n)^2 inside the band). Its variance is the 2D integral
    2 pi A (1/n_lo - 1/n_hi) = (pi/2) Gd(n0) n0^2 (1/n_lo - 1/n_hi). That is pi/2 times the
    integral of the 1D PSD over the same band, Gd(n0) n0^2 (1/n_lo - 1/n_hi): a profile of an
    isotropic field also sees the oblique waves with |n| >= n_lo but along-profile frequency
    below n_lo, so its 1D PSD is not zero below n_lo (it levels off at A (1/n_lo^2 - 1/n_hi^2)).
    Both are checked: the total against the 2D integral, and the in-band 1D PSD is what the
    tests above fit.

    The ensemble variance of every point is estimated by the mean of z^2 over the grid and
    48 seeds (the field has zero mean: no DC term). Subtracting each patch's own mean would
    remove the long waves (up to 91 m) that carry most of the variance. dx = 0.2 keeps it
    fast; the band's top (2.83) then exceeds Nyquist (2.5), which changes 1/n_hi by a
    negligible 0.4 % of 1/n_lo. The FFT domain (>= 1/(n_lo dx) cells) is larger than the
    bounds, so the patch is a window of the periodic field, which is fine for the point variance.
    """
    n_lo, n_hi = ISO8608_BAND
    gd = ISO_CLASSES["C"]
    expected_2d = math.pi / 2 * gd * N0**2 * (1 / n_lo - 1 / n_hi)
    in_band_1d = gd * N0**2 * (1 / n_lo - 1 / n_hi)
    ms = [np.mean(iso8608_surface("C", (0, 0, 90, 90), seed, dx=0.2).heights ** 2)
          for seed in range(48)]
    var = float(np.mean(ms))
    assert var == pytest.approx(expected_2d, rel=0.2), (var, expected_2d, in_band_1d)
    assert var > in_band_1d * 1.2  # the isotropic field's profiles carry more than the 1D band


def test_iso8608_rejects_bad_input():
    with pytest.raises(RoadtwinError, match="ISO 8608 class"):
        iso8608_surface("Z", (0, 0, 1, 1), 0)
    with pytest.raises(RoadtwinError, match="spacing"):
        iso8608_surface("C", (0, 0, 1, 1), 0, dx=0.0)
    with pytest.raises(RoadtwinError, match="spacing"):
        iso8608_surface("C", (0, 0, 1, 1), 0, dx=float("nan"))


# --------------------------------------------------------------------------- SampledSurface
def test_sampled_reproduces_tilted_plane():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-50, 50, (400, 2))
    plane = lambda p: 3.2 + 0.07 * p[:, 0] - 0.031 * p[:, 1]  # noqa: E731
    s = SampledSurface(np.c_[xy, plane(xy)])
    q = rng.uniform(-60, 60, (2000, 2))  # inside and a little outside the samples
    np.testing.assert_allclose(s.height(q), plane(q), atol=1e-9, rtol=0)


def smooth(x, y):
    return 0.1 * np.sin(x / 5) + 0.05 * np.cos(y / 7)


def test_sampled_smooth_function_error_bound():
    """Bound for the local plane fit on a grid of spacing h with k = 8 neighbours.

    The fitted intercept is sum_i l_i z_i with sum l_i = 1 and sum l_i (p_i - q) = 0, so the
    linear part of the Taylor expansion cancels and the error is sum_i l_i R_i with
    |R_i| <= M |p_i - q|^2 / 2, M = max ||Hessian||_2 = max(0.1/25, 0.05/49) = 0.004 1/m.
    For q in a grid cell the 8 nearest samples lie within sqrt(5) h (the cell's corners and
    the four next nodes all do), and for this stencil sum |l_i| <= 1.04 (a few negative
    weights of -0.013 at most; measured over 20k positions in a cell), so
    |error| <= 1.04 * M * 5 h^2 / 2 = 2.6 mm at h = 0.5 m. Plain IDW would miss by the
    gradient times ~h/2, up to 0.02 * 0.25 = 5 mm.
    """
    h = 0.5
    g = np.arange(0.0, 40.0 + h / 2, h)
    X, Y = np.meshgrid(g, g)
    s = SampledSurface(np.c_[X.ravel(), Y.ravel(), smooth(X, Y).ravel()])
    rng = np.random.default_rng(5)
    q = rng.uniform(1.0, 39.0, (5000, 2))
    q = q[np.abs(q / h - np.round(q / h)).min(axis=1) > 1e-3]  # off-grid
    err = np.abs(s.height(q) - smooth(q[:, 0], q[:, 1]))
    bound = 1.04 * 0.004 * 5 * h**2 / 2
    assert err.max() <= bound
    # and on average far better than the worst case (measured ~0.1 mm RMS)
    assert np.sqrt(np.mean(err**2)) < bound / 5


def test_sampled_exact_at_samples():
    rng = np.random.default_rng(9)
    pts = np.c_[rng.uniform(0, 10, (200, 2)), rng.normal(0, 1, 200)]  # rough, not a plane
    s = SampledSurface(pts)
    assert np.array_equal(s.height(pts[:, :2]), pts[:, 2])
    assert s.height(pts[17, :2])[0] == pts[17, 2]  # a single (2,) query works too


def test_sampled_needs_three_finite_points():
    with pytest.raises(RoadtwinError):
        SampledSurface(np.zeros((2, 3)))
    with pytest.raises(RoadtwinError):
        SampledSurface(np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.nan]], dtype=float))


# --------------------------------------------------------------------------- GridSurface
def bilinear(x, y):
    return 0.4 - 0.02 * x + 0.035 * y + 0.0017 * x * y


def grid_surface(f, x0=-2.0, y0=3.0, dx=0.25, nx=41, ny=23):
    xs = x0 + dx * np.arange(nx)
    ys = y0 + dx * np.arange(ny)
    X, Y = np.meshgrid(xs, ys)  # heights[i, j] at (x0 + j dx, y0 + i dx)
    return GridSurface(x0, y0, dx, f(X, Y)), X, Y


def test_grid_bilinear_exact():
    s, X, Y = grid_surface(bilinear)
    rng = np.random.default_rng(2)
    q = np.c_[rng.uniform(X.min(), X.max(), 3000), rng.uniform(Y.min(), Y.max(), 3000)]
    np.testing.assert_allclose(s.height(q), bilinear(q[:, 0], q[:, 1]), atol=1e-12, rtol=0)


def test_grid_nodes_exact():
    rng = np.random.default_rng(4)
    s, X, Y = grid_surface(lambda x, y: rng.normal(size=x.shape))
    q = np.c_[X.ravel(), Y.ravel()]
    np.testing.assert_allclose(s.height(q), s.heights.ravel(), atol=1e-8, rtol=0)
    # a node is reproduced to rounding: the largest neighbour difference times ~1e-9
    assert np.abs(s.height(q) - s.heights.ravel()).max() < 1e-8


# --------------------------------------------------------------------------- parse_surface
BOUNDS = (0.0, 0.0, 20.0, 6.0)


def test_parse_flat():
    s = parse_surface("flat", BOUNDS, 0)
    assert isinstance(s, FlatSurface) and s.height(np.zeros((3, 2))).tolist() == [0.0] * 3
    s = parse_surface("flat:2.5", BOUNDS, 0)
    assert s.height(np.array([[1.0, 2.0]]))[0] == 2.5


@pytest.mark.parametrize("spec,dx", [("iso8608:C", 0.1), ("iso8608:c:0.2", 0.2),
                                     (" ISO8608:C ", 0.1)])
def test_parse_iso8608(spec, dx):
    s = parse_surface(spec, BOUNDS, 3)
    assert isinstance(s, GridSurface)
    assert s.dx == pytest.approx(dx)
    ref = iso8608_surface("C", BOUNDS, 3, dx=dx)
    assert np.array_equal(s.heights, ref.heights)


@pytest.mark.parametrize("spec,words", [
    ("iso8608:Z", ["'Z'", "A..H"]),
    ("nope", ["'nope'", "flat", "iso8608"]),
    ("iso8608", ["class", "iso8608:C"]),
    ("flat:abc", ["flat:abc"]),
    ("iso8608:C:zero", ["iso8608:C:zero"]),
    ("iso8608:C:0", ["spacing"]),
])
def test_parse_errors_are_helpful(spec, words):
    with pytest.raises(RoadtwinError) as exc:
        parse_surface(spec, BOUNDS, 0)
    msg = str(exc.value)
    assert msg.startswith("surface:")
    for w in words:
        assert w in msg, msg


def test_parse_adds_terrain():
    g = np.arange(-1.0, 22.0, 1.0)
    X, Y = np.meshgrid(g, np.arange(-1.0, 8.0, 1.0))
    terrain_z = 12.0 + 0.03 * X - 0.01 * Y  # a tilted plane the sampled model reproduces
    terrain = np.c_[X.ravel(), Y.ravel(), terrain_z.ravel()]
    q = np.random.default_rng(0).uniform((0, 0), (20, 6), (500, 2))
    plane = 12.0 + 0.03 * q[:, 0] - 0.01 * q[:, 1]

    flat = parse_surface("flat:0.5", BOUNDS, 0, terrain=terrain)
    assert isinstance(flat, SumSurface)
    np.testing.assert_allclose(flat.height(q), plane + 0.5, atol=1e-9)

    rough = parse_surface("iso8608:C", BOUNDS, 4, terrain=terrain)
    alone = parse_surface("iso8608:C", BOUNDS, 4)
    np.testing.assert_allclose(rough.height(q), plane + alone.height(q), atol=1e-9)

    # empty terrain means none
    assert isinstance(parse_surface("flat", BOUNDS, 0, terrain=np.zeros((0, 3))), FlatSurface)
