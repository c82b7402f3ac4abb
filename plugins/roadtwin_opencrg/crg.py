"""ASAM OpenCRG ``.crg`` files: read, write, and evaluate as a surface model.

Format, as the shipped files describe it in their own comment blocks (and OpenCRG 1.2):

* A text header of blocks, each starting with a ``$NAME`` line: ``$CT`` (free comment text),
  ``$ROAD_CRG`` (``KEY = VALUE`` reference line / grid parameters), ``$ROAD_CRG_OPTS`` and
  ``$ROAD_CRG_MODS`` (runtime options / modifiers, kept as given), ``$KD_Definition`` (``#:FMT``
  format, an optional virtual ``U:`` channel, and one ``D:name,unit`` line per data channel).
  A lone ``$`` or ``$!...`` line closes a block; ``*`` in column 1 is a comment, ``!`` starts an
  in-line comment. Keys are case-insensitive.
* A separator line starting with ``$$$$``, then the data: one row per reference-line point
  (u = start_u + i * increment), one value per ``D:`` channel.
* ``LRFI`` / ``LDFI``: text, 80-character records of 8 x 10 (real) or 4 x 20 (double) fixed-width
  fields; fields may touch (``0.0000000-0.0111111``), so they are cut by width, not by blanks.
  Each row starts a new record and wraps when it has more channels than a record holds. A
  field whose text starts with ``*`` (``*missing*``, ``**unused**``) is NaN.
* ``KRBI`` / ``KDBI``: big-endian IEEE float32 / float64 filling 80-byte records one after the
  other (rows do not start new records); the last record is padded with NaN.

Channels understood: ``reference line phi`` (heading, rad), ``reference line x`` / ``y``,
``reference line slope`` (m/m), ``reference line banking`` (m/m), and the long sections, either
``long section at v = V`` (explicit v) or ``long section N`` (equidistant v from
``LONG_SECTION_V_RIGHT/LEFT/INCREMENT``; with only the increment, centred on the reference line).

Reference line: the phi/slope value of row i (i >= 1) is the heading/slope of the interval from
point i-1 to point i (row 0 is ``**unused**``), as in ``handmade_circle.crg`` where
``REFERENCE_LINE_START_PHI`` equals row 1 and ``END_PHI`` the last row. Points are integrated
from ``REFERENCE_LINE_START_X/Y/Z`` (default 0): ``x_i = x_{i-1} + du cos(phi_i)``; without a phi
channel the line is straight at ``START_PHI``. Banking is a per-point cross slope: ``z += b(u) v``.

Missing cells (NaN): :class:`CrgSurface` follows OpenCRG's ``GRID_NAN_MODE`` from
``$ROAD_CRG_MODS`` (default 2): 0 keeps NaN, 1 sets 0, 2 ("keep last") takes the nearest valid
value of the same long row (cross section) in v, ties towards the reference line; a row
with no valid value copies the nearest row in u; ``GRID_NAN_OFFSET`` is added to filled cells.
A :class:`RuntimeWarning` says how many cells were filled. :func:`read_crg` itself keeps NaN, so
round trips are exact.

Known damage: the shipped ``belgian_block.crg`` (KRBI) is 6 bytes short of whole 80-byte records
and from row 92 on its floats were shifted: the file went through a CRLF -> LF newline conversion
that dropped ``\\r`` bytes out of the binary data. When binary data is short of whole records and
the first channel is the reference line heading, :func:`_repair_lost_cr` puts the lost ``\\r``
bytes back (each before a ``\\n``, located where the heading stops being continuous) and warns.
For belgian_block that restores 6 bytes, after which the integrated reference line ends at the
header's ``REFERENCE_LINE_END_X/Y`` to 1 mm and the heights are a smooth 2.04..2.18 m. If the
repair does not fit, the file is read as is with a warning.
"""
from __future__ import annotations

import math
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from roadtwin_core import RoadtwinError, SurfaceModel
from roadtwin_core.atomic import atomic_write_bytes

FORMATS = {"LRFI": ("text", 10, 8), "LDFI": ("text", 20, 4), "KRBI": ("bin", 4, 20), "KDBI": ("bin", 8, 10)}
RECORD = 80
SEPARATOR = "$" * 72
_LS_V = re.compile(r"^long\s+section\s+at\s+v\s*=\s*(\S+)$")
_LS_N = re.compile(r"^long\s+section\b")


@dataclass
class CRG:
    """One OpenCRG file's content.

    ``z[i, j]`` is the height at (u[i], v[j]) relative to the reference line (NaN = missing).
    ``phi``/``slope``/``banking``/``ref_x``/``ref_y`` are the raw reference line channels as
    stored (row 0 of phi/slope is unused), or None; ``x``, ``y``, ``heading``, ``z_ref`` are the
    reference line points derived from them (see the module doc).
    """

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    z_ref: np.ndarray
    phi: np.ndarray | None = None
    slope: np.ndarray | None = None
    banking: np.ndarray | None = None
    ref_x: np.ndarray | None = None
    ref_y: np.ndarray | None = None
    road: dict[str, float | str] = field(default_factory=dict)
    options: dict[str, float | str] = field(default_factory=dict)
    modifiers: dict[str, float | str] = field(default_factory=dict)
    comments: list[str] = field(default_factory=list)
    fmt: str = "LDFI"
    v_explicit: bool = False
    source: str = ""      # the file read (a referencing file, if it was one)
    data_file: str = ""   # the file the grid came from

    @property
    def shape(self) -> tuple[int, int]:
        return self.z.shape

    @property
    def missing(self) -> int:
        return int(np.isnan(self.z).sum())

    @classmethod
    def from_grid(cls, u: np.ndarray, v: np.ndarray, z: np.ndarray, *, x0: float = 0.0, y0: float = 0.0,
                  phi0: float = 0.0, phi: np.ndarray | None = None, comments: list[str] | None = None,
                  z0: float = 0.0) -> "CRG":
        """Build a CRG from an equidistant u grid, a v grid, heights and an optional phi channel."""
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        inc = float(u[1] - u[0]) if len(u) > 1 else 1.0
        road: dict[str, float | str] = {
            "reference_line_start_u": float(u[0]), "reference_line_end_u": float(u[-1]),
            "reference_line_increment": inc, "reference_line_start_x": float(x0),
            "reference_line_start_y": float(y0), "reference_line_start_phi": float(phi0),
            "reference_line_start_z": float(z0),
            "long_section_v_right": float(v[0]), "long_section_v_left": float(v[-1])}
        dv = np.diff(v)
        explicit = not (len(v) > 1 and np.allclose(dv, dv[0], rtol=0, atol=1e-12))
        if not explicit and len(v) > 1:
            road["long_section_v_increment"] = float(dv[0])
        crg = cls(u=u, v=v, z=np.asarray(z, dtype=np.float64), x=np.zeros(len(u)), y=np.zeros(len(u)),
                  heading=np.zeros(len(u)), z_ref=np.zeros(len(u)),
                  phi=None if phi is None else np.asarray(phi, dtype=np.float64), road=road,
                  comments=list(comments or []), v_explicit=explicit)
        _derive_reference_line(crg, "CRG")
        return crg


# ----------------------------------------------------------------------------------------- reading
# Numbers. A well-formed number (what C's strtod and MATLAB's %f read in full: digits, an optional
# point, an optional e/E exponent; ".5" and "5." included) means what it says. Three forms the
# ASAM examples and Fortran-era IPLOS writers produce are read as their writer meant, with a
# warning: a D exponent ("1.0D+01" = 10), the exponent sign before the letter ("2.0+e00", in
# handmade_platform.crg) and Fortran's letterless exponent ("0.1234-105", mantissa with a point).
# Python-only spellings (``1_0``, ``infinity``) are not numbers; nan/inf are refused in headers.
_WELL_FORMED = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_FORTRAN = re.compile(r"(?P<m>[+-]?(?:\d+\.?\d*|\.\d+))(?:[dD](?P<e1>[+-]?\d+)|(?P<s2>[+-])[eEdD](?P<e2>\d+)"
                      r"|(?P<s3>[+-])(?P<e3>\d{1,3}))")
_DECIMAL_COMMA = re.compile(r"[+-]?\d*,\d+")
MAX_VALUES = 100_000_000  # values (rows x channels) read from one file: 800 MB as float64
MAX_HEADER_ABS = 1e12     # |header number|: beyond this, squares and sums lose all meaning
MAX_REF_DEPTH = 8         # $ROAD_CRG_FILE nesting (the Rust opencrg crate's limit)
_NUMERIC_KEYS = {
    "ROAD_CRG": {f"reference_line_{a}_{b}" for a in ("start", "end")
                 for b in ("u", "x", "y", "z", "phi", "b", "s", "lon", "lat", "alt")}
                | {"reference_line_increment", "long_section_v_right", "long_section_v_left", "long_section_v_increment",
                   "reference_line_offset_x", "reference_line_offset_y", "reference_line_offset_z",
                   "reference_line_offset_phi"},
    "ROAD_CRG_OPTS": {"border_mode_u", "border_mode_v", "border_offset_u", "border_offset_v", "border_smooth_ubeg",
                      "border_smooth_uend", "refline_continuation", "refline_search_far", "refline_search_close",
                      "warn_msgs", "warn_curv_local", "warn_curv_global", "log_msgs", "log_eval", "log_eval_freq",
                      "log_hist", "log_hist_freq", "log_stat", "log_stat_freq", "check_eps", "check_inc", "check_tol",
                      "check_pro", "check_wgs"},
    "ROAD_CRG_MODS": {"scale_z_grid", "scale_slope", "scale_banking", "scale_length", "scale_width",
                      "scale_curvature", "grid_nan_mode", "grid_nan_offset", "refline_rotcenter_x",
                      "refline_rotcenter_y", "refline_offset_phi", "refline_offset_x", "refline_offset_y",
                      "refline_offset_z", "refpoint_u", "refpoint_u_fraction", "refpoint_u_offset", "refpoint_v",
                      "refpoint_v_fraction", "refpoint_v_offset", "refpoint_x", "refpoint_y", "refpoint_z",
                      "refpoint_phi"},
}


def _number(text: str) -> tuple[float | None, str]:
    """(value, how): how is "" for a well-formed number, else what was read non-strictly."""
    if _WELL_FORMED.fullmatch(text):
        return float(text), ""
    m = _FORTRAN.fullmatch(text)
    if m and (m.group("s3") is None or "." in m.group("m")):
        exp = m.group("e1") or (m.group("s2") or m.group("s3") or "") + (m.group("e2") or m.group("e3"))
        return float(f"{m.group('m')}e{exp}"), "Fortran-style exponent"
    return None, ""


def _header_number(text: str, where: str, notes: list[str]) -> float | None:
    """A header value as a number (see above); trailing text after a number is dropped with a
    note, as ASAM's readers do (``%f`` / ``strtod`` stop there). None: not a number at all."""
    val, how = _number(text)
    if val is None and _DECIMAL_COMMA.match(text):
        raise RoadtwinError(f"{where}: {text!r} is not a number (decimal comma?)")
    if val is None:
        best = None
        for k in range(len(text) - 1, 0, -1):  # longest numeric prefix
            val, how = _number(text[:k])
            if val is not None:
                best = (val, text[:k])
                break
        if best is None:
            return None
        val, how = best[0], f"read as {best[1]}"
    if not math.isfinite(val) or abs(val) > MAX_HEADER_ABS:
        raise RoadtwinError(f"{where}: {text!r} is out of range (|value| <= {MAX_HEADER_ABS:g})")
    if how:
        notes.append(f"{where}: malformed number {text!r} ({how}: {val!r})")
    return val


def _parse_header(text: str) -> dict:
    blocks: dict[str, list[str]] = {}
    current: str | None = None
    for raw in text.splitlines():
        line = raw.rstrip("\r")
        if line.startswith("$"):
            name = line[1:].split("!", 1)[0].strip().upper()
            current = name if name and not name.startswith("!") else None
            if current is not None:
                blocks.setdefault(current, [])
            continue
        if current is None:
            continue
        if current == "CT":
            blocks[current].append(line.rstrip())
            continue
        if line.startswith("*"):
            continue
        line = line.split("!", 1)[0].strip()
        if line:
            blocks[current].append(line)
    return blocks


def _kv(lines: list[str], path: Path, block: str, notes: list[str]) -> dict[str, float | str]:
    out: dict[str, float | str] = {}
    numeric = _NUMERIC_KEYS.get(block, set())
    for line in lines:
        if "=" not in line:
            raise RoadtwinError(f"{path}: ${block}: expected KEY = VALUE, got {line!r}")
        k, val = line.split("=", 1)
        key, val = k.strip().lower(), val.strip()
        num = _header_number(val, f"{path}: ${block} {k.strip()}", notes)
        if num is None and key in numeric:
            raise RoadtwinError(f"{path}: ${block} {k.strip()} = {val!r}: not a number")
        out[key] = val if num is None else num
    return out


def read_crg(path: str | Path) -> CRG:
    """Read an OpenCRG file (LRFI, LDFI, KRBI or KDBI), or a file that only references one.

    A referencing file has a ``$ROAD_CRG_FILE`` block naming the file with the data (relative to
    the referencing file; the name may be split over several lines, which are joined after their
    ``!`` comments and surrounding blanks are removed; ``$VAR`` is an environment variable) and
    may have its own ``$ROAD_CRG_MODS`` / ``$ROAD_CRG_OPTS``. As in ASAM's ``crg_read.m`` and the
    C loader, the least nested block wins whole: a referencing file's MODS block replaces the
    referenced file's MODS block (its keys are not merged). References may nest
    (``MAX_REF_DEPTH``); a cycle is refused. Bad input raises a one-line RoadtwinError naming the
    file (and the files that referenced it); warnings are issued only for a file that reads.
    """
    notes: list[str] = []
    crg = _read(Path(path), (), notes)
    for note in notes:
        warnings.warn(note, RuntimeWarning, stacklevel=2)
    return crg


def _read_bytes(path: Path) -> bytes:
    try:
        if path.is_dir():
            raise RoadtwinError(f"{path}: is a directory, not an OpenCRG file")
        size = path.stat().st_size
        if size > 8 * MAX_VALUES + (1 << 20):
            raise RoadtwinError(f"{path}: {size / 1e9:.1f} GB is larger than an OpenCRG file roadtwin reads "
                                f"({MAX_VALUES:,} values)")
        return path.read_bytes()
    except OSError as exc:
        raise RoadtwinError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _read(path: Path, chain: tuple[str, ...], notes: list[str]) -> CRG:
    data = _read_bytes(path)
    m = re.search(rb"(?m)^\$\$\$\$[^\n]*\n?", data)
    header = (data if m is None else data[:m.start()]).decode("latin-1")
    blocks = _parse_header(header)
    if "ROAD_CRG_FILE" in blocks:
        return _read_referencing(path, blocks, m is not None, chain, notes)
    if m is None:
        raise RoadtwinError(f"{path}: not an OpenCRG file (no $$$$ separator before the data and no "
                            "$ROAD_CRG_FILE reference)")
    body = data[m.end():]
    kd = blocks.get("KD_DEFINITION")
    if kd is None:
        raise RoadtwinError(f"{path}: no $KD_Definition block")
    fmt = None
    channels: list[str] = []
    for line in kd:
        tag, _, rest = line.partition(":")
        tag = tag.strip().upper()
        if tag == "#":
            fmt = rest.strip().upper()
        elif tag == "D":
            channels.append(rest.split(",", 1)[0].strip().lower())
    if fmt is None:
        raise RoadtwinError(f"{path}: $KD_Definition has no #: data format line (OpenCRG knows {', '.join(FORMATS)})")
    if fmt not in FORMATS:
        raise RoadtwinError(f"{path}: unknown data format {fmt!r} (OpenCRG knows {', '.join(FORMATS)})")
    if not channels:
        raise RoadtwinError(f"{path}: $KD_Definition defines no D: channels")
    road = _kv(blocks.get("ROAD_CRG", []), path, "ROAD_CRG", notes)
    opts = _kv(blocks.get("ROAD_CRG_OPTS", []), path, "ROAD_CRG_OPTS", notes)
    mods = _kv(blocks.get("ROAD_CRG_MODS", []), path, "ROAD_CRG_MODS", notes)
    kind, width, per_rec = FORMATS[fmt]
    nch = len(channels)
    if kind == "text":
        values = _read_text(body, nch, width, per_rec, path, notes)
    else:
        values = _read_binary(body, nch, width, fmt, path, road, notes)
    _check_values(values, channels, path)
    crg = _assemble(values, channels, road, path)
    crg.options, crg.modifiers, crg.fmt = opts, mods, fmt
    crg.comments = [c for c in blocks.get("CT", [])]
    crg.data_file = str(path)
    return crg


def _read_referencing(path: Path, blocks: dict, has_data: bool, chain: tuple[str, ...], notes: list[str]) -> CRG:
    """A file that carries only a $ROAD_CRG_FILE reference (+ its own MODS / OPTS / CT)."""
    extra = [f"${b}" for b in ("ROAD_CRG", "KD_DEFINITION") if b in blocks] + (["data after $$$$"] if has_data else [])
    if extra:
        raise RoadtwinError(f"{path}: has a $ROAD_CRG_FILE reference and also {', '.join(extra)} (a referencing "
                            "file carries only $ROAD_CRG_FILE, $ROAD_CRG_MODS, $ROAD_CRG_OPTS and $CT)")
    name = "".join(blocks["ROAD_CRG_FILE"])
    try:  # the header is ISO-8859-1, but file systems name files in UTF-8: take that where it fits
        name = name.encode("latin-1").decode("utf-8")
    except UnicodeDecodeError:
        pass
    if not name:
        raise RoadtwinError(f"{path}: $ROAD_CRG_FILE names no file")

    def env(m: re.Match) -> str:
        var = m.group(1) or m.group(2)
        if var not in os.environ:
            raise RoadtwinError(f"{path}: $ROAD_CRG_FILE {name!r}: environment variable ${var} is not set")
        return os.environ[var]

    expanded = re.sub(r"\$\{(\w+)\}|\$(\w+)", env, name)
    target = Path(expanded)
    if not target.is_absolute():
        target = path.parent / target
    here = os.path.realpath(path)
    chain = chain + (here,)
    if os.path.realpath(target) in chain:
        cycle = " -> ".join(list(chain) + [os.path.realpath(target)])
        raise RoadtwinError(f"{path}: $ROAD_CRG_FILE reference cycle: {cycle}")
    if len(chain) > MAX_REF_DEPTH:
        raise RoadtwinError(f"{path}: $ROAD_CRG_FILE references nest deeper than {MAX_REF_DEPTH} files")
    try:
        crg = _read(target, chain, notes)
    except RoadtwinError as exc:
        msg = str(exc)
        if msg.endswith(")") and " (referenced by " in msg:  # nested: one list, innermost first
            raise RoadtwinError(f"{msg[:-1]} <- {path})") from None
        raise RoadtwinError(f"{msg} (referenced by {path})") from None
    if "ROAD_CRG_OPTS" in blocks:
        crg.options = _kv(blocks["ROAD_CRG_OPTS"], path, "ROAD_CRG_OPTS", notes)
    if "ROAD_CRG_MODS" in blocks:
        crg.modifiers = _kv(blocks["ROAD_CRG_MODS"], path, "ROAD_CRG_MODS", notes)
    crg.source = str(path)
    return crg


def _too_large(path: Path, nrows: float, nch: int) -> None:
    if not nrows * nch <= MAX_VALUES:
        raise RoadtwinError(f"{path}: grid of {nrows:.4g} rows x {nch} channels = {nrows * nch:.4g} values "
                            f"({nrows * nch * 8 / 1e9:.3g} GB as float64) is too large (limit {MAX_VALUES:,} values)")


def _field(s: str, path: Path, r: int, col: int) -> tuple[float, bool]:
    """One text data field -> (value, read non-strictly). ``*...`` and ``nan`` are missing."""
    if s.startswith("*") or s.lower() == "nan":
        return math.nan, False
    val, how = _number(s)
    if val is None:
        raise RoadtwinError(f"{path}: data row {r + 1}, channel {col + 1}: not a number: {s!r}")
    return val, bool(how)


def _read_text(body: bytes, nch: int, width: int, per_rec: int, path: Path, notes: list[str]) -> np.ndarray:
    lines = body.decode("latin-1").replace("\r\n", "\n").split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise RoadtwinError(f"{path}: no data after the $$$$ separator")
    per_row = math.ceil(nch / per_rec)
    if len(lines) % per_row:
        raise RoadtwinError(f"{path}: truncated data: {len(lines)} records is not a whole number of "
                            f"{nch}-channel rows ({per_row} records each)")
    nrows = len(lines) // per_row
    _too_large(path, nrows, nch)
    out = np.empty((nrows, nch))
    odd = 0
    for r in range(nrows):
        col = 0
        for k in range(per_row):
            line = lines[r * per_row + k]
            nf = min(per_rec, nch - col)
            if line[nf * width:].strip():
                raise RoadtwinError(f"{path}: data row {r + 1} has more values than the {nch} channels defined")
            if len(line.rstrip()) <= (nf - 1) * width:
                raise RoadtwinError(f"{path}: data row {r + 1} has fewer values than the {nch} channels defined "
                                    "(truncated?)")
            for f in range(nf):
                s = line[f * width:(f + 1) * width].strip()
                if not s:
                    raise RoadtwinError(f"{path}: data row {r + 1} has an empty field (truncated?)")
                out[r, col], nonstrict = _field(s, path, r, col)
                odd += nonstrict
                col += 1
    if odd:
        notes.append(f"{path}: {odd} data value(s) with a Fortran-style exponent (e.g. 1.0D+01) read as meant")
    return out


def _check_values(values: np.ndarray, channels: list[str], path: Path) -> None:
    """No infinities anywhere; heights, slopes, banking and headings within +-1e6, reference line
    x/y within +-MAX_HEADER_ABS (NaN is a missing value and passes)."""
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(values) <= MAX_HEADER_ABS) & ~np.isnan(values)
        for j, name in enumerate(channels):
            if " ".join(name.split()) not in ("reference line x", "reference line y"):
                bad[:, j] |= np.abs(values[:, j]) > 1e6
    if bad.any():
        r, j = (int(i) for i in np.argwhere(bad)[0])
        raise RoadtwinError(f"{path}: data row {r + 1}, channel {channels[j]!r}: value {values[r, j]:g} is out of "
                            f"range ({int(bad.sum())} such value(s))")


def _read_binary(body: bytes, nch: int, size: int, fmt: str, path: Path, road: dict, notes: list[str]) -> np.ndarray:
    dtype = ">f4" if size == 4 else ">f8"
    nvals = len(body) // size
    if isinstance(road.get("reference_line_end_u"), float) and isinstance(road.get("reference_line_increment"), float) \
            and road["reference_line_increment"] > 0:
        span = (road["reference_line_end_u"] - float(road.get("reference_line_start_u", 0.0))) \
            / road["reference_line_increment"]
        if not span >= 0:
            raise RoadtwinError(f"{path}: REFERENCE_LINE_END_U is before REFERENCE_LINE_START_U")
        _too_large(path, span + 1, nch)
        nrows = int(round(span)) + 1
        if nrows * nch > nvals:
            raise RoadtwinError(f"{path}: truncated {fmt} data: {nrows} rows x {nch} channels need "
                                f"{nrows * nch * size} bytes, file has {len(body)}")
    else:
        nrows = nvals // nch
    if nrows < 1:
        raise RoadtwinError(f"{path}: truncated {fmt} data: not one full row of {nch} channels")
    _too_large(path, nrows, nch)
    need = nrows * nch * size
    repaired = None
    if len(body) < -(-need // RECORD) * RECORD and len(body) >= need - 64:
        with np.errstate(invalid="ignore", over="ignore"):
            repaired = _repair_lost_cr(body, nch, size, dtype, nrows)
        if repaired is None and len(body) % RECORD and len(body) % RECORD != 1:  # a trailing newline is fine
            notes.append(f"{path}: {fmt} data is {len(body)} bytes, not whole {RECORD}-byte records: the file may "
                         "have been damaged (e.g. by a CRLF -> LF conversion); values may be shifted")
        if repaired is not None:
            short = -(-need // RECORD) * RECORD - len(body.rstrip(b"\n"))
            notes.append(f"{path}: {fmt} data was {short} "
                         "bytes short of whole records; restored CR bytes lost by a CRLF -> LF conversion "
                         f"({len(repaired) - len(body)} inserted, located by reference line heading continuity)")
            body = repaired
    vals = np.frombuffer(body[:need], dtype=dtype).astype(np.float64).reshape(nrows, nch)
    if "reference_line_end_u" not in road:
        # drop trailing all-NaN rows that are only the last record's NaN padding
        pad_rows = RECORD // (nch * size)
        while pad_rows > 0 and len(vals) > 1 and np.isnan(vals[-1]).all():
            vals = vals[:-1]
            pad_rows -= 1
    return vals


def _repair_lost_cr(body: bytes, nch: int, size: int, dtype: str, nrows: int, tol: float = 0.05,
                    max_fix: int = 64) -> bytes | None:
    """Undo a CRLF -> LF conversion of binary data, if the first channel is a smooth heading.

    Each lost byte was a ``\\r`` before a ``\\n``. Walking the rows, the first row whose first
    channel (reference line phi) jumps by more than ``tol`` rad marks a loss between it and the
    previous row; a ``\\r`` is inserted before the ``\\n`` in that span that leaves the previous
    row's values smoothest. Returns None when the file does not fit that picture.
    """
    data = bytearray(body)
    row = nch * size
    start = 2
    for _ in range(max_fix):
        n = min(len(data) // row, nrows)
        vals = np.frombuffer(bytes(data[:n * row]), dtype=dtype).astype(np.float64).reshape(n, nch)
        phi = vals[:, 0]
        jump = ~(np.abs(np.diff(phi[1:])) < tol)
        bad = np.where(jump)[0]
        bad = bad[bad + 2 >= start]
        if not len(bad):
            if n == nrows and len(data) >= -(-nrows * row // RECORD) * RECORD - 1:
                return bytes(data)
            return None
        r = int(bad[0]) + 2  # first row whose phi is off
        lo, hi = (r - 1) * row, r * row + size
        cands = [p for p in range(lo, hi) if data[p] == 0x0A]
        if not cands:
            return None
        best, score = None, np.inf
        for p in cands:
            trial = bytes(data[lo:p]) + b"\r" + bytes(data[p:hi])
            v = np.frombuffer(trial[:row], dtype=dtype).astype(np.float64)
            nxt = np.frombuffer(trial[row:row + size], dtype=dtype)[0]
            if not abs(nxt - phi[r - 1]) < tol:
                continue
            z = v[1:]
            z = z[np.isfinite(z)]
            sc = np.abs(np.diff(z)).sum() if len(z) > 1 else 0.0
            if not np.isfinite(sc) or np.abs(z).max(initial=0) > 1e3:
                sc = np.inf
            if sc < score:
                best, score = p, sc
        if best is None:
            return None
        data[best:best] = b"\r"
        start = r + 1
    return None


def _assemble(values: np.ndarray, channels: list[str], road: dict, path: Path) -> CRG:
    nrows = len(values)
    inc = float(road.get("reference_line_increment", 0.0) or 0.0)
    u0 = float(road.get("reference_line_start_u", 0.0))
    if "reference_line_increment" in road and not inc > 0:
        raise RoadtwinError(f"{path}: REFERENCE_LINE_INCREMENT must be positive, got {road['reference_line_increment']}")
    if not inc > 0:
        if "reference_line_end_u" in road and nrows > 1:
            inc = (float(road["reference_line_end_u"]) - u0) / (nrows - 1)
        if not inc > 0:
            raise RoadtwinError(f"{path}: $ROAD_CRG needs a positive REFERENCE_LINE_INCREMENT")
    if "reference_line_end_u" in road:
        expect = (float(road["reference_line_end_u"]) - u0) / inc + 1
        _too_large(path, expect, len(channels))
        if abs(expect - nrows) > 1e-6 * max(1.0, expect):
            raise RoadtwinError(f"{path}: {nrows} data rows, but REFERENCE_LINE_START_U/END_U/INCREMENT give "
                                f"{expect:g} (truncated?)")
    u = u0 + inc * np.arange(nrows)
    if nrows > 1 and not (np.diff(u) > 0).all():
        raise RoadtwinError(f"{path}: REFERENCE_LINE_INCREMENT {inc:g} is too small to step from "
                            f"REFERENCE_LINE_START_U {u0:g}")
    ref: dict[str, np.ndarray] = {}
    ls_idx: list[int] = []
    ls_v: list[float | None] = []
    for i, name in enumerate(channels):
        name = " ".join(name.split())
        mv = _LS_V.match(name)
        if mv:
            try:
                ls_v.append(float(mv.group(1)))
            except ValueError:
                raise RoadtwinError(f"{path}: channel {name!r}: bad v position") from None
            ls_idx.append(i)
        elif _LS_N.match(name):
            ls_v.append(None)
            ls_idx.append(i)
        elif name in ("reference line phi", "reference line x", "reference line y", "reference line slope",
                      "reference line banking"):
            ref[name.split()[-1]] = values[:, i].copy()
        else:
            raise RoadtwinError(f"{path}: unknown data channel {name!r}")
    nv = len(ls_idx)
    if nv < 2:
        raise RoadtwinError(f"{path}: needs at least 2 long section channels, found {nv}")
    explicit = all(x is not None for x in ls_v)
    if explicit:
        v = np.array(ls_v, dtype=np.float64)
    elif any(x is not None for x in ls_v):
        raise RoadtwinError(f"{path}: mixes long sections with and without explicit v")
    else:
        v = _equidistant_v(road, nv, path)
    if np.any(np.diff(v) <= 0):
        raise RoadtwinError(f"{path}: long section v positions must increase from right to left")
    for key, val in (("long_section_v_right", v[0]), ("long_section_v_left", v[-1])):
        if key in road and abs(float(road[key]) - val) > 1e-6:
            raise RoadtwinError(f"{path}: {key.upper()} = {road[key]} but the long section channels give {val:g}")
    crg = CRG(u=u, v=v, z=values[:, ls_idx].copy(), x=np.zeros(nrows), y=np.zeros(nrows),
              heading=np.zeros(nrows), z_ref=np.zeros(nrows), phi=ref.get("phi"), slope=ref.get("slope"),
              banking=ref.get("banking"), ref_x=ref.get("x"), ref_y=ref.get("y"), road=road,
              v_explicit=explicit, source=str(path))
    _derive_reference_line(crg, str(path))
    return crg


def _equidistant_v(road: dict, nv: int, path: Path) -> np.ndarray:
    r, l, inc = (road.get(k) for k in ("long_section_v_right", "long_section_v_left", "long_section_v_increment"))
    r = None if r is None else float(r)
    l = None if l is None else float(l)
    inc = None if inc is None else float(inc)
    if inc is None:
        if r is None or l is None:
            raise RoadtwinError(f"{path}: long sections need LONG_SECTION_V_INCREMENT or explicit v positions")
        inc = (l - r) / (nv - 1)
    if not inc > 0:
        raise RoadtwinError(f"{path}: LONG_SECTION_V_INCREMENT must be positive")
    if r is not None and l is not None:
        n = (l - r) / inc + 1
        if abs(n - nv) > 1e-6 * max(1.0, n):
            raise RoadtwinError(f"{path}: wrong channel count: LONG_SECTION_V_RIGHT/LEFT/INCREMENT give {n:g} "
                                f"long sections, $KD_Definition has {nv}")
    if r is None:
        r = l - (nv - 1) * inc if l is not None else -(nv - 1) * inc / 2.0
    return r + inc * np.arange(nv)


def _derive_reference_line(crg: CRG, where: str) -> None:
    n = len(crg.u)
    road = crg.road
    du = np.diff(crg.u)
    x0 = float(road.get("reference_line_start_x", 0.0))
    y0 = float(road.get("reference_line_start_y", 0.0))
    z0 = float(road.get("reference_line_start_z", 0.0))
    phi0 = float(road.get("reference_line_start_phi", 0.0))
    if crg.phi is not None:
        seg = crg.phi[1:].copy()
        if n > 1 and np.isnan(seg).any():
            raise RoadtwinError(f"{where}: reference line phi has missing values")
    else:
        seg = np.full(n - 1, phi0)
    if crg.ref_x is not None and crg.ref_y is not None:
        x, y = crg.ref_x.copy(), crg.ref_y.copy()
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise RoadtwinError(f"{where}: reference line x/y have missing values")
        if crg.phi is None and n > 1:
            seg = np.arctan2(np.diff(y), np.diff(x))
    else:
        x = np.concatenate([[x0], x0 + np.cumsum(du * np.cos(seg))])
        y = np.concatenate([[y0], y0 + np.cumsum(du * np.sin(seg))])
    heading = np.concatenate([[seg[0] if n > 1 else phi0], seg]) if n > 1 else np.array([phi0])
    if crg.slope is not None and n > 1:
        sl = np.nan_to_num(crg.slope[1:])
        zr = np.concatenate([[z0], z0 + np.cumsum(du * sl)])
    else:
        zr = np.full(n, z0)
    crg.x, crg.y, crg.heading, crg.z_ref = x, y, heading, zr


# ----------------------------------------------------------------------------------------- writing
def _fmt_field(val: float, width: int) -> str:
    if not math.isfinite(val):
        return "*missing*".rjust(width)
    s = repr(float(val))
    if s.endswith(".0"):
        s = s[:-1] + "0"
    if len(s) > width and ("0." in s[:3]):
        s = s.replace("0.", ".", 1)  # "-.045000000000000005": 20 characters, same value
    if len(s) > width:  # fields may touch (as in the shipped files): the reader cuts by width
        for p in range(17, 0, -1):
            s = f"{val:.{p}e}"
            if len(s) <= width:
                break
    return s.rjust(width)


def _header_value(val: float | str) -> str:
    return repr(float(val)) if isinstance(val, (int, float)) else str(val)


def _channels(crg: CRG) -> tuple[list[str], np.ndarray]:
    names: list[str] = []
    cols: list[np.ndarray] = []
    for key, arr, unit in (("phi", crg.phi, "rad"), ("x", crg.ref_x, "m"), ("y", crg.ref_y, "m"),
                           ("slope", crg.slope, "m/m"), ("banking", crg.banking, "m/m")):
        if arr is not None:
            names.append(f"reference line {key},{unit}")
            cols.append(np.asarray(arr, dtype=np.float64))
    for j, vj in enumerate(crg.v):
        names.append(f"long section at v = {float(vj)!r},m" if crg.v_explicit else f"long section {j + 1},m")
        cols.append(crg.z[:, j])
    return names, np.column_stack(cols)


def crg_bytes(crg: CRG, binary: bool, double: bool | None = None) -> bytes:
    double = (not binary) if double is None else double
    fmt = ("KDBI" if double else "KRBI") if binary else ("LDFI" if double else "LRFI")
    names, values = _channels(crg)
    road = dict(crg.road)
    road["reference_line_start_u"] = float(crg.u[0])
    road["reference_line_end_u"] = float(crg.u[-1])
    if len(crg.u) > 1:
        road.setdefault("reference_line_increment", float(crg.u[1] - crg.u[0]))
    road["long_section_v_right"] = float(crg.v[0])
    road["long_section_v_left"] = float(crg.v[-1])
    if crg.v_explicit:
        road.pop("long_section_v_increment", None)
    # a comment line must not open a block ("$...") or be read as the data separator
    out = ["$CT"] + [f"% {c}" if c.startswith("$") else c for c in crg.comments] + ["$", "$ROAD_CRG"]
    out += [f"{k.upper()} = {_header_value(v)}" for k, v in road.items()]
    for block, kv in (("ROAD_CRG_OPTS", crg.options), ("ROAD_CRG_MODS", crg.modifiers)):
        if kv:
            out += ["$", f"${block}"] + [f"{k.upper()} = {_header_value(v)}" for k, v in kv.items()]
    out += ["$", "$KD_Definition", f"#:{fmt}", f"U:reference line u,m,{float(crg.u[0])!r},"
            f"{float(road.get('reference_line_increment', 1.0))!r}"]
    out += [f"D:{n}" for n in names]
    out += ["$", SEPARATOR]
    head = ("\n".join(out) + "\n").encode("latin-1")
    if binary:
        raw = values.astype(">f8" if double else ">f4").tobytes()
        size = 8 if double else 4
        pad = (-len(raw)) % RECORD
        raw += np.full(pad // size, np.nan, dtype=">f8" if double else ">f4").tobytes()
        return head + raw
    _, width, per_rec = FORMATS[fmt]
    lines = []
    for row in values:
        for k in range(0, len(row), per_rec):
            lines.append("".join(_fmt_field(float(x), width) for x in row[k:k + per_rec]))
    return head + ("\n".join(lines) + "\n").encode("latin-1")


def write_crg(path: str | Path, crg: CRG, binary: bool = False, double: bool | None = None) -> Path:
    """Write ``crg``: text ``LDFI`` (double) or binary ``KRBI`` (float32) by default.

    ``double`` overrides the precision (text LRFI with ``double=False``, binary KDBI with
    ``double=True``). Written atomically. Text fields carry the shortest repr that round-trips
    the float64 value when it fits the field (20 characters LDFI, 10 LRFI; all values of the
    shipped files do); longer ones fall back to the most digits that fit (about 15 significant
    in LDFI), so text is exact for values with a short decimal form, binary KDBI always.
    """
    return atomic_write_bytes(path, crg_bytes(crg, binary, double), parents=False)   # as before: no folders made


# ----------------------------------------------------------------------------------------- surface
def fill_missing(z: np.ndarray, mode: int = 2, offset: float = 0.0, v: np.ndarray | None = None) -> np.ndarray:
    """OpenCRG GRID_NAN_MODE: 0 keep NaN, 1 zero, 2 nearest valid value in the row (keep last)."""
    z = np.array(z, dtype=np.float64)
    bad = np.isnan(z)
    if not bad.any() or mode == 0:
        return z
    if mode == 1:
        z[bad] = 0.0 + offset
        return z
    nu, nv = z.shape
    vv = np.arange(nv, dtype=np.float64) if v is None else np.asarray(v, dtype=np.float64)
    out = z.copy()
    rows_ok = ~bad.all(axis=1)
    if not rows_ok.any():
        raise RoadtwinError("CRG: every grid cell is missing")
    order = np.argsort(vv, kind="stable")
    for i in np.where(bad.any(axis=1) & rows_ok)[0]:
        good = order[~bad[i, order]]  # valid columns, by increasing v
        miss = np.where(bad[i])[0]
        pos = np.searchsorted(vv[good], vv[miss])
        lo = good[np.clip(pos - 1, 0, len(good) - 1)]
        hi = good[np.clip(pos, 0, len(good) - 1)]
        dlo, dhi = np.abs(vv[lo] - vv[miss]), np.abs(vv[hi] - vv[miss])
        # the nearer valid value in v; ties towards the reference line (smaller |v|)
        take_hi = (dhi < dlo) | ((dhi == dlo) & (np.abs(vv[hi]) < np.abs(vv[lo])))
        out[i, miss] = z[i, np.where(take_hi, hi, lo)] + offset
    okrows = np.where(rows_ok)[0]
    for i in np.where(~rows_ok)[0]:
        out[i] = out[okrows[np.argmin(np.abs(okrows - i))]]
    return out


class CrgSurface(SurfaceModel):
    """An OpenCRG road as a :class:`SurfaceModel`: world xy -> (u, v) -> bilinear grid height.

    The reference line is the polyline of the points integrated from phi; a point (u, v) lies at
    ``c(u) + v n(u)`` with ``n`` the left normal interpolated linearly between the bisector
    normals at the interval ends, so (u, v) is continuous across the polyline's corners (no gaps or
    double cover on either side, within the curvature radius); :meth:`uv` inverts it exactly. Outside the grid, u and
    v are clamped (OpenCRG's default border mode 2, "keep last"). The height is
    ``z_ref(u) + banking(u) * v + grid(u, v)`` with missing cells filled per ``GRID_NAN_MODE``.
    """

    name = "crg"

    def __init__(self, crg: CRG, nan_mode: int | None = None, warn: bool = True) -> None:
        self.crg = crg
        mods = crg.modifiers
        try:
            mode = nan_mode if nan_mode is not None else int(float(mods.get("grid_nan_mode", 2)))
            offset = float(mods.get("grid_nan_offset", 0.0))
        except ValueError:
            raise RoadtwinError(f"{crg.source or 'CRG'}: GRID_NAN_MODE/OFFSET must be numbers") from None
        if mode not in (0, 1, 2):
            raise RoadtwinError(f"{crg.source or 'CRG'}: GRID_NAN_MODE must be 0, 1 or 2, got {mode}")
        if mode and crg.z.size and np.isnan(crg.z).all():
            raise RoadtwinError(f"{crg.source or 'CRG'}: every grid cell is missing")
        self.grid = fill_missing(crg.z, mode, offset, crg.v)
        filled = crg.missing - int(np.isnan(self.grid).sum())
        if filled and warn:
            warnings.warn(f"{crg.source or 'CRG'}: filled {filled} missing cell(s) (GRID_NAN_MODE {mode})",
                          RuntimeWarning, stacklevel=2)
        self.points = np.column_stack([crg.x, crg.y])
        self.tree = cKDTree(self.points)
        self._nrm = self._normals() if len(self.points) > 1 else np.array([[0.0, 1.0]])

    @classmethod
    def from_file(cls, path: str | Path, **kw) -> "CrgSurface":
        return cls(read_crg(path), **kw)

    def _normals(self) -> np.ndarray:
        """Unit left normals at the reference line points: bisectors of the adjacent intervals."""
        d = np.diff(self.points, axis=0)
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        nseg = np.column_stack([-d[:, 1], d[:, 0]])
        nv = np.vstack([nseg[:1], nseg[:-1] + nseg[1:], nseg[-1:]])
        return nv / np.maximum(np.linalg.norm(nv, axis=1, keepdims=True), 1e-300)

    def uv(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World xy (N,2) -> (u, v) along the reference line (unclamped); inverse of :meth:`world`."""
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        p = self.points
        n = len(p)
        if n < 2:
            return np.full(len(xy), self.crg.u[0]), xy[:, 1] - p[0, 1]
        k = min(6, n)
        _, idx = self.tree.query(xy, k=k)
        idx = np.atleast_2d(idx).reshape(len(xy), k)
        seg = np.clip(np.concatenate([idx - 1, idx], axis=1), 0, n - 2)  # candidate intervals
        a, d = p[seg], p[seg + 1] - p[seg]
        n0, m = self._nrm[seg], self._nrm[seg + 1] - self._nrm[seg]
        w = xy[:, None, :] - a

        def cross(x, y):
            return x[..., 0] * y[..., 1] - x[..., 1] * y[..., 0]

        # w = t d + v (n0 + t m)  =>  A t^2 + B t + C = 0 (cross with n(t) eliminates v)
        A, B, C = cross(d, m), cross(d, n0) - cross(w, m), -cross(w, n0)
        with np.errstate(divide="ignore", invalid="ignore"):
            lin = -C / B
            disc = np.sqrt(np.maximum(B * B - 4 * A * C, 0.0))
            r1 = (-B + disc) / (2 * A)
            r2 = (-B - disc) / (2 * A)
        quad = np.abs(A) > 1e-12 * np.maximum(np.abs(B), 1e-300)
        pick = np.where(np.abs(r1 - 0.5) <= np.abs(r2 - 0.5), r1, r2)
        t = np.where(quad, pick, lin)
        t = np.where(np.isfinite(t), t, 0.0)
        nt = n0 + t[..., None] * m
        v = ((w - t[..., None] * d) * nt).sum(-1) / np.maximum((nt * nt).sum(-1), 1e-300)
        inside = (t >= -1e-9) & (t <= 1 + 1e-9)
        inside |= ((seg == 0) & (t < 0)) | ((seg == n - 2) & (t > 1))
        cost = np.where(inside, np.abs(v), np.inf)
        best = np.argmin(cost, axis=1)
        r = np.arange(len(xy))
        sb, tb, vb = seg[r, best], t[r, best], v[r, best]
        u = self.crg.u[sb] + tb * (self.crg.u[sb + 1] - self.crg.u[sb])
        lost = ~np.isfinite(cost[r, best])
        if lost.any():  # should not happen; fall back to the nearest reference line point
            j = idx[lost, 0]
            u[lost] = self.crg.u[j]
            vb[lost] = ((xy[lost] - p[j]) * self._nrm[j]).sum(-1)
        return u, vb

    def world(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(u, v) -> world xy: the reference line point at u plus v times the left normal, the
        normal interpolated linearly between the interval ends (bisectors), so the map is
        continuous and invertible (by :meth:`uv`) within the curvature radius."""
        u = np.atleast_1d(np.asarray(u, dtype=np.float64))
        v = np.atleast_1d(np.asarray(v, dtype=np.float64))
        c = self.crg
        n = len(c.u)
        if n < 2:
            return np.column_stack([np.full(u.shape, c.x[0]), c.y[0] + v])
        s = np.clip(np.searchsorted(c.u, u, side="right") - 1, 0, n - 2)
        t = (u - c.u[s]) / (c.u[s + 1] - c.u[s])
        a, b = self.points[s], self.points[s + 1]
        nt = self._nrm[s] + t[:, None] * (self._nrm[s + 1] - self._nrm[s])
        return a + t[:, None] * (b - a) + v[:, None] * nt

    def height_uv(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        c = self.crg
        u = np.clip(np.asarray(u, dtype=np.float64), c.u[0], c.u[-1])
        vc = np.clip(np.asarray(v, dtype=np.float64), c.v[0], c.v[-1])
        fu = (u - c.u[0]) / (c.u[1] - c.u[0]) if len(c.u) > 1 else np.zeros_like(u)
        i = np.clip(np.floor(fu).astype(np.int64), 0, max(len(c.u) - 2, 0))
        tu = np.clip(fu - i, 0.0, 1.0) if len(c.u) > 1 else np.zeros_like(u)
        j = np.clip(np.searchsorted(c.v, vc, side="right") - 1, 0, len(c.v) - 2)
        tv = (vc - c.v[j]) / (c.v[j + 1] - c.v[j])
        g = self.grid
        i1 = np.minimum(i + 1, len(c.u) - 1)
        h = ((1 - tu) * (1 - tv) * g[i, j] + tu * (1 - tv) * g[i1, j]
             + (1 - tu) * tv * g[i, j + 1] + tu * tv * g[i1, j + 1])
        zr = np.interp(u, c.u, c.z_ref)
        if c.banking is not None:
            zr = zr + np.interp(u, c.u, np.nan_to_num(c.banking)) * vc
        return h + zr

    def height(self, xy: np.ndarray) -> np.ndarray:
        u, v = self.uv(xy)
        return self.height_uv(u, v)
