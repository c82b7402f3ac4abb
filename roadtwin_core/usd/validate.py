"""Run every registered ``pxr.UsdValidation`` validator on a stage."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pxr import Usd, UsdValidation

from ..errors import RoadtwinError


@dataclass
class Finding:
    severity: str
    validator: str
    message: str
    sites: list[str]


def validate_stage(path: str | Path) -> list[Finding]:
    path = Path(path)
    if not path.exists():
        raise RoadtwinError(f"{path}: no such file")
    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:
        raise RoadtwinError(f"{path}: not a readable USD stage ({str(exc).strip().splitlines()[-1]})") from None
    registry = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    findings = []
    for err in ctx.Validate(stage):
        if err.HasNoError():
            continue
        validator = err.GetValidator()
        name = validator.GetMetadata().name if validator else ""
        sites = [str(s.GetPrim().GetPath()) if s.IsPrim() else str(s.GetLayer().identifier if s.GetLayer() else "")
                 for s in err.GetSites()]
        findings.append(Finding(str(err.GetType()).rsplit(".", 1)[-1], name, err.GetMessage(), sites))
    return findings
