"""The OpenCRG plugin: every shipped file reads, round trips, missing cells, heights, bad files,
and the ``crg`` exporter on a composed town.

Expected values come from the files themselves (header lines and data blocks parsed here with a
few lines of independent code) or from analytic surfaces written by the test.
"""
from __future__ import annotations

import math
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from roadtwin_core import PluginManager, RoadtwinError, SurfaceModel

ROOT = Path(__file__).resolve().parents[2]
try:
    import roadtwin_opencrg
except ImportError:  # not yet in the installed entry points / package list
    sys.path.insert(0, str(ROOT / "plugins"))
    import roadtwin_opencrg

from roadtwin_opencrg import CRG, CrgSurface, read_crg, write_crg  # noqa: E402

DATA = ROOT / "tests" / "data" / "opencrg"
FILES = sorted(p.name for p in DATA.glob("*.crg"))


def header(path: Path) -> dict[str, float]:
    """KEY = number lines before the data separator, lower-cased (independent of the plugin)."""
    raw = path.read_bytes()
    text = raw[:raw.index(b"\n$$$$")].decode("latin-1")
    out = {}
    for line in text.splitlines():
        m = re.match(r"^\s*([A-Za-z_]+)\s*=\s*([-+0-9.eE]+)\s*(!.*)?$", line)
        if m and not line.startswith("*"):
            try:
                out[m.group(1).lower()] = float(m.group(2))
            except ValueError:
                pass
    return out


def read(name: str) -> CRG:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return read_crg(DATA / name)


@pytest.fixture(scope="module")
def crgs() -> dict[str, CRG]:
    return {name: read(name) for name in FILES}


def test_shipped_files_present():
    assert len(FILES) == 12 and "belgian_block.crg" in FILES
    assert (DATA / "LICENSE").exists()


@pytest.mark.parametrize("name", FILES)
def test_every_shipped_file_reads(crgs, name):
    crg = crgs[name]
    h = header(DATA / name)
    nu, nv = crg.shape
    assert nu >= 2 and nv >= 2 and crg.z.shape == (len(crg.u), len(crg.v))
    inc = h["reference_line_increment"]
    assert np.allclose(np.diff(crg.u), inc)
    assert crg.u[0] == pytest.approx(h.get("reference_line_start_u", 0.0))
    if "reference_line_end_u" in h:
        assert crg.u[-1] == pytest.approx(h["reference_line_end_u"])
    if "long_section_v_right" in h:
        assert crg.v[0] == pytest.approx(h["long_section_v_right"])
        assert crg.v[-1] == pytest.approx(h["long_section_v_left"])
    if "long_section_v_increment" in h:
        assert np.allclose(np.diff(crg.v), h["long_section_v_increment"])
    n_d = len(re.findall(rb"(?mi)^D:long section", (DATA / name).read_bytes()))
    assert nv == n_d
    # finite data apart from documented missing cells
    assert np.isfinite(crg.x).all() and np.isfinite(crg.y).all() and np.isfinite(crg.z_ref).all()
    if "reference_line_end_phi" in h and crg.phi is not None:
        assert math.remainder(crg.heading[-1] - h["reference_line_end_phi"], 2 * math.pi) == pytest.approx(0, abs=1e-6)


def test_belgian_block_binary(crgs):
    crg = crgs["belgian_block.crg"]
    h = header(DATA / "belgian_block.crg")
    assert crg.fmt == "KRBI" and crg.shape == (1001, 341)
    assert crg.u[0] == 730.0 and crg.u[-1] == pytest.approx(740.0)
    # the integrated heading reproduces the header's end point: data aligned after the CR repair
    assert crg.x[-1] == pytest.approx(h["reference_line_end_x"], abs=0.01)
    assert crg.y[-1] == pytest.approx(h["reference_line_end_y"], abs=0.01)
    z = crg.z[np.isfinite(crg.z)]
    assert 2.0 < z.min() and z.max() < 2.2  # measured cobblestones, no shifted-float garbage
    assert np.nanmax(np.abs(np.diff(crg.z, axis=0))) < 0.05
    with pytest.warns(RuntimeWarning, match="CRLF"):
        read_crg(DATA / "belgian_block.crg")


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def _f32(a):
    return None if a is None else np.asarray(a, dtype=np.float32).astype(np.float64)


@pytest.mark.parametrize("name", FILES)
def test_round_trip(crgs, tmp_path, name):
    crg = crgs[name]
    txt = read_crg(write_crg(tmp_path / "t.crg", crg, binary=False))
    assert txt.fmt == "LDFI"
    for attr in ("u", "v", "z", "phi", "slope", "banking", "x", "y", "z_ref"):
        assert _same(getattr(txt, attr), getattr(crg, attr)), attr
    assert txt.options == crg.options and txt.modifiers == crg.modifiers
    binr = read_crg(write_crg(tmp_path / "b.crg", crg, binary=True))
    assert binr.fmt == "KRBI" and (tmp_path / "b.crg").stat().st_size % 80 == len(
        (tmp_path / "b.crg").read_bytes().split(b"$" * 72 + b"\n", 1)[0] + b"$" * 72 + b"\n") % 80
    assert _same(binr.u, crg.u) and _same(binr.v, crg.v)
    for attr in ("z", "phi", "slope", "banking"):
        assert _same(getattr(binr, attr), _f32(getattr(crg, attr))), attr
    dbl = read_crg(write_crg(tmp_path / "d.crg", crg, binary=True, double=True))
    assert dbl.fmt == "KDBI" and _same(dbl.z, crg.z) and _same(dbl.phi, crg.phi)


def test_lrfi_round_trip(crgs, tmp_path):
    crg = crgs["handmade_curved.crg"]
    back = read_crg(write_crg(tmp_path / "r.crg", crg, binary=False, double=False))
    assert back.fmt == "LRFI" and _same(back.z, crg.z) and _same(back.phi, crg.phi)


def _data_block(path: Path, width: int = 10) -> np.ndarray:
    lines = path.read_text("latin-1").split("\n")
    start = next(i for i, l in enumerate(lines) if l.startswith("$$$$")) + 1
    rows = []
    for line in lines[start:]:
        if not line.strip():
            continue
        fields = [line[k:k + width].strip() for k in range(0, len(line.rstrip()), width)]
        rows.append([np.nan if f.startswith("*") else float(f) for f in fields])
    return np.array(rows)


def test_straight_matches_data_block(crgs):
    ref = _data_block(DATA / "handmade_straight.crg")
    crg = crgs["handmade_straight.crg"]
    assert ref.shape == (23, 7) and _same(crg.z, ref)
    assert np.allclose(crg.v, np.linspace(-1.5, 1.5, 7)) and np.allclose(crg.u, np.arange(23.0))
    surf = CrgSurface(crg, warn=False)
    assert isinstance(surf, SurfaceModel)
    uu, vv = np.meshgrid(crg.u, crg.v, indexing="ij")
    ok = np.isfinite(ref)
    # straight reference line along +x from the origin: world (x, y) = (u, v)
    got = surf.height(np.column_stack([uu.ravel(), vv.ravel()])).reshape(ref.shape)
    assert np.allclose(got[ok], ref[ok], atol=1e-12)
    # cell centres are the mean of the four corners (bilinear)
    i, j = 4, 2
    mid = surf.height(np.array([[crg.u[i] + 0.5, crg.v[j] + 0.25]]))[0]
    assert mid == pytest.approx(ref[i:i + 2, j:j + 2].mean(), abs=1e-12)
    # double file holds the same surface
    dbl = crgs["handmade_straight_double.crg"]
    assert np.allclose(dbl.z, crg.z, atol=1e-6, equal_nan=True)
    assert _same(crgs["handmade_straight_minimalist.crg"].z, crg.z)
    assert np.allclose(crgs["handmade_straight_minimalist.crg"].v, crg.v)


def test_missing_cells_modes(crgs):
    crg = crgs["handmade_straight.crg"]
    assert crg.missing == 3
    nan_rows, nan_cols = np.where(np.isnan(crg.z))
    assert list(zip(nan_rows, nan_cols)) == [(7, 0), (7, 6), (8, 0)]
    with pytest.warns(RuntimeWarning, match="filled 3 missing"):
        keep = CrgSurface(crg)
    # GRID_NAN_MODE 2 (default): nearest valid value in the same cross section
    assert keep.grid[7, 0] == crg.z[7, 1] and keep.grid[7, 6] == crg.z[7, 5] and keep.grid[8, 0] == crg.z[8, 1]
    assert np.isfinite(keep.height(np.array([[7.0, -1.5]])))[0]
    zero = CrgSurface(crg, nan_mode=1, warn=False)
    assert zero.grid[7, 0] == 0.0 and zero.grid[8, 0] == 0.0
    keepnan = CrgSurface(crg, nan_mode=0, warn=False)
    assert np.isnan(keepnan.height(np.array([[7.0, -1.5]])))[0]
    # the platform file's GRID_NAN_MODE is malformed ("2.000000000+e00"): read as 2 with a warning
    with pytest.warns(RuntimeWarning, match="malformed"):
        plat = read_crg(DATA / "handmade_platform.crg")
    assert plat.modifiers["grid_nan_mode"] == 2.0


def test_reference_line_channels(crgs):
    sloped = crgs["handmade_sloped.crg"]
    slope = _data_block(DATA / "handmade_sloped.crg")[:, 0]
    assert sloped.z_ref[-1] == pytest.approx(np.nansum(slope[1:]) * 1.0)
    s = CrgSurface(sloped, warn=False)
    assert s.height(np.array([[22.0, 0.0]]))[0] == pytest.approx(sloped.z_ref[-1] + sloped.z[-1, 3])
    banked = crgs["handmade_banked.crg"]
    bank = _data_block(DATA / "handmade_banked.crg")[:, 0]
    b = CrgSurface(banked, warn=False)
    assert b.height(np.array([[11.0, 1.5]]))[0] == pytest.approx(bank[11] * 1.5 + banked.z[11, -1])
    # circle: 24 intervals of 10 m, headings 0.25 .. -0.25 rad
    circ = crgs["handmade_circle.crg"]
    phi = _data_block(DATA / "handmade_circle.crg")[1:, 0]
    assert circ.x[-1] == pytest.approx(10 * np.cos(phi).sum()) and circ.y[-1] == pytest.approx(10 * np.sin(phi).sum())


def test_curved_analytic_surface(tmp_path):
    """A plane z = a u + b v on an arc reference line: bilinear is exact, so heights are too."""
    u = np.arange(0, 30.0001, 0.5)
    v = np.array([-2.0, -1.0, -0.25, 0.0, 0.5, 1.5, 2.0])  # non-equidistant: explicit v channels
    a, b = 0.01, -0.03
    z = np.round(a * u[:, None] + b * v[None, :], 9)  # short decimals: text is exact for them
    phi = np.concatenate([[np.nan], 0.3 + 0.02 * np.arange(1, len(u))])
    crg = CRG.from_grid(u, v, z, x0=5.0, y0=-3.0, phi0=0.32, phi=phi, comments=["analytic plane on an arc"])
    back = read_crg(write_crg(tmp_path / "plane.crg", crg, binary=False))
    assert back.v_explicit and _same(back.v, v) and _same(back.z, z)
    surf = CrgSurface(back)
    rng = np.random.default_rng(0)
    uq = rng.uniform(0.1, 29.9, 200)
    vq = rng.uniform(-1.9, 1.9, 200)
    xy = surf.world(uq, vq)
    u2, v2 = surf.uv(xy)
    assert np.allclose(u2, uq, atol=1e-9) and np.allclose(v2, vq, atol=1e-9)
    assert np.allclose(surf.height(xy), a * uq + b * vq, atol=1e-9)
    # beyond the grid: clamped (OpenCRG border mode "keep last")
    far = surf.world(np.array([10.0]), np.array([0.0])) + 100 * np.array([[-np.sin(0.5), np.cos(0.5)]])
    assert np.isfinite(surf.height(far)).all()


def _corrupt(tmp_path: Path, name: str, edit) -> Path:
    text = (DATA / name).read_text("latin-1")
    p = tmp_path / f"bad_{name}"
    p.write_text(edit(text), "latin-1")
    return p


def _one_line_error(path: Path, match: str):
    with pytest.raises(RoadtwinError, match=match) as exc:
        read_crg(path)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_bad_files(tmp_path):
    lines = (DATA / "handmade_straight.crg").read_text("latin-1").splitlines()
    # truncated: last row cut short, or rows missing against REFERENCE_LINE_END_U
    _one_line_error(_corrupt(tmp_path, "handmade_straight.crg", lambda t: t.rstrip("\n")[:-25] + "\n"), "fewer values")
    _one_line_error(_corrupt(tmp_path, "handmade_straight.crg", lambda t: "\n".join(lines[:-3]) + "\n"), "truncated")
    # unknown format
    _one_line_error(_corrupt(tmp_path, "handmade_straight.crg", lambda t: t.replace("#:LRFI", "#:XYZW")),
                    "unknown data format")
    # wrong channel count: one long section definition less than V_RIGHT/LEFT/INCREMENT imply
    drop = lambda t: t.replace("D:long section 7,m", "", 1)  # noqa: E731
    _one_line_error(_corrupt(tmp_path, "handmade_straight.crg", drop), "channels")
    mini = lambda t: t.replace("D:long section 7,m\n", "", 1)  # noqa: E731
    _one_line_error(_corrupt(tmp_path, "handmade_straight_minimalist.crg", mini), "more values")
    _one_line_error(_corrupt(tmp_path, "handmade_straight.crg",
                             lambda t: t.replace("LONG_SECTION_V_INCREMENT = 0.50", "LONG_SECTION_V_INCREMENT = 0.25")),
                    "wrong channel count")
    # unknown channel, not a CRG, missing file
    _one_line_error(_corrupt(tmp_path, "handmade_sloped.crg", lambda t: t.replace("reference line slope", "wobble")),
                    "unknown data channel")
    nocrg = tmp_path / "x.crg"
    nocrg.write_text("hello\n")
    _one_line_error(nocrg, "not an OpenCRG file")
    _one_line_error(tmp_path / "missing.crg", "cannot read")
    # truncated binary
    crg = read("handmade_curved.crg")
    b = write_crg(tmp_path / "b.crg", crg, binary=True)
    raw = b.read_bytes()
    b.write_bytes(raw[:len(raw) - 200])
    _one_line_error(b, "truncated KRBI")


# ----------------------------------------------------------------------------------------- exporter
@pytest.fixture(scope="module")
def town(tmp_path_factory) -> Path:
    from roadtwin_core.apps.compose.run import compose

    out = tmp_path_factory.mktemp("crgtown") / "town"
    return compose(ROOT / "stages/town.usda", out, defects=8, seed=3, preview=False, surface="flat").town


def test_exporter_registered():
    pm = PluginManager(load_entry_points=False)
    pm.register(roadtwin_opencrg, name="opencrg")
    exp = pm.registry("exporters")["crg"]
    assert exp.suffix == ".crg" and exp.name == "crg"


def _reference_heights(verts, faces, xy):
    """Brute-force vertical rays with the core Möller–Trumbore test on nearby triangles."""
    from roadtwin_core.geometry import vertical_ray_hits

    tri = verts[faces]
    out = []
    for p in xy:
        near = np.where((np.abs(tri[..., :2] - p).max(axis=2) < 3.0).all(axis=1))[0]
        hits = vertical_ray_hits(p[None], tri[near])[0]
        zs = []
        for t in tri[near][hits]:
            n = np.cross(t[1] - t[0], t[2] - t[0])
            zs.append(t[0, 2] - (n[0] * (p[0] - t[0, 0]) + n[1] * (p[1] - t[0, 1])) / n[2])
        out.append(max(zs) if zs else np.nan)
    return np.array(out)


def test_export_lane(town, tmp_path):
    from roadtwin_core.usd import load_town, read_layout

    pm = PluginManager(load_entry_points=False)
    pm.register(roadtwin_opencrg, name="opencrg")
    out = pm.registry("exporters")["crg"].export(town, tmp_path / "lane.crg")
    crg = read_crg(out)
    assert crg.fmt == "KRBI" and crg.missing == 0
    assert np.allclose(np.diff(crg.u), 0.05) and np.allclose(np.diff(crg.v), 0.05)
    assert crg.v[0] == pytest.approx(-crg.v[-1]) and 1.0 < crg.v[-1] <= 1.75
    # the reference line follows the chosen lane chain's centerline
    layout = read_layout(next((town.parent / "layout").glob("*.usda")))
    chain = roadtwin_opencrg.lane_chain(layout)
    total = sum(np.linalg.norm(np.diff(s.centerline, axis=0), axis=1).sum() for s in chain)
    assert crg.u[-1] == pytest.approx(total, abs=0.05 + 1e-9)
    assert np.hypot(crg.x[0] - chain[0].centerline[0, 0], crg.y[0] - chain[0].centerline[0, 1]) < 1e-6
    end = chain[-1].centerline[-1]
    assert np.hypot(crg.x[-1] - end[0], crg.y[-1] - end[1]) < 0.06
    # heights: the collision mesh under the grid points, checked by brute force at sampled cells
    verts, faces = load_town(town).collision_mesh()
    surf = CrgSurface(crg, warn=False)
    rng = np.random.default_rng(1)
    iu = rng.integers(0, len(crg.u), 40)
    iv = rng.integers(0, len(crg.v), 40)
    xy = surf.world(crg.u[iu], crg.v[iv])
    ref = _reference_heights(verts, faces, xy)
    assert np.allclose(crg.z[iu, iv], ref.astype(np.float32), atol=1e-5)
    assert np.allclose(surf.height(xy), crg.z[iu, iv], atol=1e-9)


def test_export_errors(tmp_path):
    from roadtwin_opencrg import CrgExporter

    with pytest.raises(RoadtwinError, match="no such file"):
        CrgExporter().export(tmp_path / "nope.usda", tmp_path / "x.crg")
    assert not (tmp_path / "x.crg").exists()


@pytest.fixture(scope="module")
def arc_town(tmp_path_factory) -> Path:
    """A one-lane 60 degree arc (radius 30 m, 3.5 m wide) on an ISO 8608 class C road."""
    from roadtwin_core import RoadSegment, TownLayout
    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.usd import write_layout

    r0, w = 30.0, 3.5
    th = np.linspace(0.0, np.pi / 3, 121)
    inner = np.column_stack([(r0 - w / 2) * np.sin(th), r0 - (r0 - w / 2) * np.cos(th), np.zeros_like(th)])
    outer = np.column_stack([(r0 + w / 2) * np.sin(th), r0 - (r0 + w / 2) * np.cos(th), np.zeros_like(th)])
    verts = np.empty((2 * len(th), 3))
    verts[0::2], verts[1::2] = outer, inner  # outer = right of travel (left turn)
    faces = []
    for i in range(len(th) - 1):
        a, b, c, d = 2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3
        faces += [(a, c, b), (b, c, d)]
    tc = np.linspace(0.0, np.pi / 3, 32)
    center = np.column_stack([r0 * np.sin(tc), r0 - r0 * np.cos(tc)])
    seg = RoadSegment("arc_0", "driving", verts, np.array(faces), centerline=center)
    d = tmp_path_factory.mktemp("arc")
    layout = write_layout(TownLayout("Arc", [seg]), d / "arc.usda")
    return compose(layout, d / "town", defects=2, seed=5, preview=False, surface="iso8608:C", executor="serial").town


def test_export_curved_lane(arc_town, tmp_path):
    from roadtwin_opencrg import CrgExporter, drape
    from roadtwin_core.usd import load_town

    crg = read_crg(CrgExporter().export(arc_town, tmp_path / "arc.crg"))
    # only the end cross sections may poke out of the mesh: the CRG normal there is the first /
    # last chord's, the segment's end edge is radial
    assert np.isfinite(crg.z[1:-1]).all() and crg.v[-1] == pytest.approx(1.7)
    assert np.isfinite(crg.z[[0, -1]]).mean() > 0.4
    # headings of the centerline's chords: 31 intervals, first and last at half an interval's turn
    assert np.ptp(crg.heading) == pytest.approx(np.pi / 3 * 30 / 31, abs=1e-3)
    assert crg.u[-1] == pytest.approx(30.0 * np.pi / 3, abs=0.1)  # chord polyline of the arc
    surf = CrgSurface(crg, warn=False)
    rng = np.random.default_rng(2)
    u = rng.uniform(crg.u[0] + 0.1, crg.u[-1] - 0.1, 400)
    v = rng.uniform(crg.v[0], crg.v[-1], 400)
    xy = surf.world(u, v)
    u2, v2 = surf.uv(xy)
    assert np.allclose(u2, u, atol=1e-6) and np.allclose(v2, v, atol=1e-6)
    # radius of the sampled points: within the lane
    r = np.hypot(xy[:, 0], xy[:, 1] - 30.0)
    assert (np.abs(r - 30.0) <= 1.75).all()
    # between the 5 cm grid nodes the CRG follows the road surface (ISO 8608 C + defects) to mm
    verts, faces = load_town(arc_town).collision_mesh()
    zm = drape(verts, faces, xy)
    assert np.isfinite(zm).all()
    err = np.abs(surf.height(xy) - zm)
    assert np.sqrt(np.mean(err ** 2)) < 1e-3 and err.max() < 0.01


# ----------------------------------------------------------------------------------------- references
def _inline_mods(text: str, mods: str) -> str:
    """``text`` with its own $ROAD_CRG_MODS block replaced by ``mods`` (placed before $KD_Definition)."""
    text = re.sub(r"(?ms)^\$ROAD_CRG_MODS.*?(?=^\$)", "", text)
    return re.sub(r"(?mi)^\$KD_Definition", lambda m: f"$ROAD_CRG_MODS\n{mods}\n$\n{m.group(0)}", text, count=1)


@pytest.mark.parametrize("name", ["handmade_straight.crg", "handmade_platform.crg", "belgian_block.crg"])
def test_reference_with_mods_equals_inline_mods(tmp_path, name):
    """A file that only references NAME and sets its own MODS gives exactly the grid, reference
    line and surface heights of NAME with those MODS written inline (the referenced file's own
    MODS block is replaced whole, as ASAM's crg_read does)."""
    mods = "GRID_NAN_MODE = 1\nGRID_NAN_OFFSET = -0.25"
    sub = tmp_path / "data dir ü"
    sub.mkdir()
    (sub / name).write_bytes((DATA / name).read_bytes())
    top = tmp_path / "top.crg"
    # the name split over lines, with comments, as the standard allows
    top.write_bytes(("$CT\nreferencing file\n$!\n$ROAD_CRG_FILE   ! data\n data dir ü/  ! folder\n* comment\n "
                     f"{name}\n$!\n$ROAD_CRG_MODS\n{mods}\n$!\n").encode("utf-8"))
    inline = tmp_path / "inline.crg"
    raw = (DATA / name).read_bytes()
    cut = raw.index(b"\n$$$$") + 1
    inline.write_bytes(_inline_mods(raw[:cut].decode("latin-1"), mods).encode("latin-1") + raw[cut:])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        a, b = read_crg(top), read_crg(inline)
        sa, sb = CrgSurface(a, warn=False), CrgSurface(b, warn=False)
    assert a.modifiers == {"grid_nan_mode": 1.0, "grid_nan_offset": -0.25} == b.modifiers
    assert a.source == str(top) and a.data_file == str(sub / name)
    for key in ("u", "v", "z", "x", "y", "heading", "z_ref"):
        assert np.array_equal(getattr(a, key), getattr(b, key), equal_nan=True), key
    assert np.array_equal(sa.grid, sb.grid)
    # independent reference for the NaN mode: missing cells became the offset, the rest as read
    miss = np.isnan(b.z)
    assert np.all(sa.grid[miss] == -0.25) and np.array_equal(sa.grid[~miss], b.z[~miss])


def test_reference_keeps_referenced_mods_and_opts_without_own(tmp_path):
    (tmp_path / "d.crg").write_bytes((DATA / "handmade_sloped_opts.crg").read_bytes())
    (tmp_path / "top.crg").write_text("$ROAD_CRG_FILE\n d.crg\n$\n")
    direct, via = read("handmade_sloped_opts.crg"), read_crg(tmp_path / "top.crg")
    assert via.options == direct.options and via.options["border_mode_u"] == 2.0
    assert np.array_equal(via.z, direct.z, equal_nan=True)


def test_reference_errors_name_the_files(tmp_path):
    (tmp_path / "a.crg").write_text("$ROAD_CRG_FILE\n sub/b.crg\n$\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.crg").write_text("$ROAD_CRG_FILE\n ../a.crg\n$\n")
    msg = _one_line_error(tmp_path / "a.crg", "reference cycle")
    assert "b.crg" in msg
    (tmp_path / "c.crg").write_text("$ROAD_CRG_FILE\n missing.crg\n$\n")
    msg = _one_line_error(tmp_path / "c.crg", "cannot read")
    assert "missing.crg" in msg and "referenced by" in msg


@pytest.mark.parametrize("text,value", [("1.0D+01", 10.0), ("-2.5d-1", -0.25), ("2.000000000+e00", 2.0),
                                        ("1.5-e02", 0.015), ("0.1234-105", 0.1234e-105), (".5", 0.5),
                                        ("-.5", -0.5), ("5.", 5.0), ("1e3", 1000.0)])
def test_number_forms(tmp_path, text, value):
    """Header and data numbers in the forms ASAM examples and Fortran writers produce; a value
    is compared with the float the text means, written by hand here."""
    t = (DATA / "handmade_straight.crg").read_text("latin-1")
    t = t.replace("$KD_Definition", f"$ROAD_CRG_MODS\nGRID_NAN_OFFSET = {text}\n$\n$KD_Definition", 1)
    head, _, data = t.partition("\n$$$$")
    sep, _, rows = data.partition("\n")
    rows = rows.splitlines()
    in_data = len(text) <= 10  # an LRFI field is 10 characters
    if in_data:
        rows[1] = text.rjust(10) + rows[1][10:]
    p = tmp_path / "n.crg"
    p.write_text(head + "\n$$$$" + sep + "\n" + "\n".join(rows) + "\n", "latin-1")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        crg = read_crg(p)
    assert crg.modifiers["grid_nan_offset"] == value and (crg.z[1, 0] == value or not in_data)
    well_formed = re.fullmatch(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", text) is not None
    assert (len(caught) == 0) == well_formed  # only non-standard forms are reported


@pytest.mark.parametrize("text", ["nan", "inf", "-Infinity", "0,5", "1e400", "one"])
def test_header_numbers_refused(tmp_path, text):
    p = _corrupt(tmp_path, "handmade_straight.crg",
                 lambda t: t.replace("REFERENCE_LINE_INCREMENT = 1.0", f"REFERENCE_LINE_INCREMENT = {text}", 1))
    _one_line_error(p, "REFERENCE_LINE_INCREMENT")


def test_absurd_grid_size_names_the_size(tmp_path):
    crg = read("handmade_curved.crg")
    b = write_crg(tmp_path / "b.crg", crg, binary=True)
    raw = b.read_bytes().replace(b"REFERENCE_LINE_END_U = 22.0", b"REFERENCE_LINE_END_U = 2200000000.0")
    b.write_bytes(raw)
    msg = _one_line_error(b, "too large")
    assert re.search(r"2\.2e\+09 rows x 8 channels", msg)
