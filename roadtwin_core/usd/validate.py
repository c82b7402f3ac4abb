"""Run every registered ``pxr.UsdValidation`` validator on a stage.

Validators that look only inside usdz packages are left out when the stage uses none: they
cannot find anything there, and on a composed Town01 the package check alone walks every layer
and asset for over a second."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pxr import Usd, UsdValidation

from ..errors import RoadtwinError


PACKAGE_KEYWORD = "UsdzValidators"  # keyword of the validators that check usdz packages only


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
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    if not any(layer.GetFileFormat().IsPackage() for layer in stage.GetUsedLayers()):
        validators = [v for v in validators if PACKAGE_KEYWORD not in v.GetMetadata().GetKeywords()]
    ctx = UsdValidation.ValidationContext(validators)
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
