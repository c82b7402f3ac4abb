"""USD at the edges: layouts in, town stages and library assets out (docs/architecture.md#usd-conventions)."""
from .layout_io import read_layout, write_layout
from .library import read_defect_asset, write_defect_asset
from .stage import apply_labels, fan_corners, new_stage, read_mesh, safe_prim_name, set_attrs, set_kind, write_mesh
from .town_reader import TownDefect, TownInstances, TownMesh, TownScene, concat_meshes, load_town
from .validate import Finding, validate_stage

__all__ = ["fan_corners", "read_layout", "write_layout", "read_defect_asset", "write_defect_asset", "apply_labels",
           "new_stage", "safe_prim_name", "set_attrs", "set_kind", "read_mesh", "write_mesh", "Finding", "validate_stage",
           "TownDefect", "TownInstances", "TownMesh", "TownScene", "concat_meshes", "load_town"]
