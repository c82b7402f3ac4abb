"""``python -m roadtwin_core.cli``: the same as the ``roadtwin`` command."""
from . import main

main()
