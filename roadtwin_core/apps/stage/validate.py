"""``roadtwin validate``: a stage's meshes read cleanly, then ``pxr.UsdValidation``'s findings."""
from __future__ import annotations

from pathlib import Path

from ...usd.checks import open_stage
from ...usd.stage import check_stage_meshes
from ...usd.validate import Finding, validate_stage

__all__ = ["validate_town"]


def validate_town(stage: str | Path) -> list[Finding]:
    """The validators' findings on ``stage``. An unreadable, badly composed or malformed stage is a
    RoadtwinError instead (the findings are for stages that can be read at all)."""
    check_stage_meshes(open_stage(stage, default_prim=False), stage)
    return validate_stage(stage)
