"""``roadtwin validate``, ``export`` and ``import``: a stage checked, a stage exported to another
tool's format, a foreign road network imported as a layout. Each checks its input first, so bad
input is one :class:`~roadtwin_core.RoadtwinError` naming the file, and nothing is written."""
from .exchange import export_stage, import_layout
from .validate import validate_town

__all__ = ["export_stage", "import_layout", "validate_town"]
