"""OpenDRIVE ``<roadMark>`` records -> the attributes of a roadtwin ``LaneMarking``.

Where a file gives no ``<type>`` line definition, standard US values are used (CARLA's towns,
the maps roadtwin imports first, are US-style: yellow centre lines), after the FHWA MUTCD
(2009, chapter 3A/3B):

- broken lines: 3 m (10 ft) line segments, 9 m (30 ft) gaps (MUTCD 3A.06, 3B.01); the same
  values the scenariogeneration/esmini OpenDRIVE tools write as their standard broken mark;
- line width 0.12 m (MUTCD: normal line 4 to 6 in, 0.10 to 0.15 m), twice that for weight bold;
- double lines: two lines with 0.12 m between them (MUTCD 3A.06: a double line is two lines
  separated by a discernible space), so centre-to-centre spacing = width + 0.12 m;
- botts dots: 0.1 m (4 in) round markers every 1.2 m (4 ft), MUTCD 3B.11-3B.14 spacing for
  markers simulating a line.

OpenDRIVE's colour "standard" means white. A double type names its lines from the inside of the
road out (left to right for the centre lane): with the marking polyline in the lane's travel
direction (right-hand traffic: right lanes and the centre lane along +s, left lanes against it)
that is always "first word on the left of travel", the order ``LaneMarking.lines()`` uses.
"""
from __future__ import annotations

from dataclasses import dataclass

from ._xodr import MarkLine, RoadMark

BROKEN_DASH_M = 3.0
BROKEN_GAP_M = 9.0
LINE_WIDTH_M = 0.12
BOLD_WIDTH_M = 0.24
DOUBLE_GAP_M = 0.12
DOT_M = 0.1
DOT_PERIOD_M = 1.2

# Types that paint nothing: "none"; a grass edge and a road "edge" are no paint either.
_NO_PAINT = ("none", "grass", "edge")


@dataclass(frozen=True)
class MarkStyle:
    """A road mark as LaneMarking attributes, plus where its paint sits relative to the border.

    ``t_shift`` moves the line (or the centre of a line pair) sideways from the lane border,
    + to the left of the reference line; ``first_dash_s`` is where the first dash starts, in s
    from the start of the mark (a ``<line sOffset>``).
    """

    marking_type: str
    color: str
    width_m: float
    dash_m: float = 0.0
    gap_m: float = 0.0
    spacing_m: float = 0.0
    t_shift: float = 0.0
    first_dash_s: float = 0.0


def _words(lines: list[MarkLine]) -> list[str]:
    return ["solid" if ln.space <= 0 or ln.length <= 0 else "broken" for ln in lines]


def mark_style(mark: RoadMark, against_s: bool) -> MarkStyle | None:
    """Style of one road mark; None for marks that paint nothing. ``against_s``: the marking
    polyline runs towards -s (left lanes), so "left of travel" is -t."""
    if mark.type in _NO_PAINT:
        return None
    # line definitions, left of travel first
    lines = sorted(mark.lines, key=lambda ln: ln.t_offset, reverse=not against_s)
    if mark.type == "custom":
        if not lines:
            return None
        lines = lines[:2]
        words = _words(lines)
        kind = "_".join(words)
    else:
        kind = mark.type.replace(" ", "_")
        words = kind.split("_") if kind not in ("botts_dots", "curb") else [kind]
    color = "white" if mark.color in ("", "standard") else mark.color
    line_width = next((ln.width for ln in lines if ln.width > 0), 0.0)
    default_width = DOT_M if kind == "botts_dots" else BOLD_WIDTH_M if mark.weight == "bold" else LINE_WIDTH_M
    width = line_width or mark.width or default_width

    double = len(words) == 2
    spacing = abs(lines[0].t_offset - lines[1].t_offset) if double and len(lines) >= 2 else 0.0
    if double and spacing <= 0:
        spacing = width + DOUBLE_GAP_M
    if double:
        t_shift = (lines[0].t_offset + lines[1].t_offset) / 2 if len(lines) >= 2 else 0.0
    else:
        t_shift = lines[0].t_offset if lines else 0.0

    dash = gap = first = 0.0
    if kind == "botts_dots":
        ln = lines[0] if lines else None
        dash = ln.length if ln and ln.length > 0 else DOT_M
        gap = ln.space if ln and ln.space > 0 else max(DOT_PERIOD_M - dash, DOT_M)
        first = ln.s_offset if ln else 0.0
    elif "broken" in words:
        k = words.index("broken")
        ln = lines[k] if k < len(lines) else (lines[0] if len(lines) == 1 else None)
        if ln is not None and ln.length > 0 and ln.space > 0:
            dash, gap, first = ln.length, ln.space, ln.s_offset
        elif ln is not None and ln.length > 0 and ln.space <= 0:
            dash = gap = 0.0  # a "broken" line without gaps is a continuous one
        else:
            dash, gap = BROKEN_DASH_M, BROKEN_GAP_M
            first = ln.s_offset if ln is not None else 0.0
    return MarkStyle(kind, color, width, dash, gap, spacing, t_shift, first)
