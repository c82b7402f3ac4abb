"""Tests mirror the package (core/, plugins/, apps/, cli/); shared helpers sit here in tests/
(``fakes.py``: a GPU-free physics backend and renderer), importable from every subfolder."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
