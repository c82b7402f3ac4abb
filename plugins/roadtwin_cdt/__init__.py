"""CDT merger: the paper's digital road twin generator, as a built-in plugin."""
from roadtwin_core import hookimpl

from .merger import CDTMerger


@hookimpl
def roadtwin_register_mergers(register):
    register(CDTMerger())
