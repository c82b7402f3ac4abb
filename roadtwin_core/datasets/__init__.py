"""Dataset readers, side by side: labelled segmentation folders, real or rendered (``folders``),
and a ``roadtwin render`` output with every modality (``render_output``). numpy + Pillow; torch
is imported when a ``Dataset`` class is first used (``_lazy_torch``). The ignore label is the
renderer's (``roadtwin_core.render.IGNORE_INDEX``)."""
from . import folders, render_output
from ._lazy_torch import lazy_classes
from .folders import (IGNORE_INDEX, IMAGE_SUFFIXES, Sample, find_pairs, load_folder, read_image, read_label,
                      read_sample)

__all__ = ["IGNORE_INDEX", "IMAGE_SUFFIXES", "Sample", "SegmentationFolder", "RenderDataset", "find_pairs",
           "load_folder", "read_image", "read_label", "read_sample"]


# the torch classes load on first use
__getattr__ = lazy_classes(__name__, {"SegmentationFolder": lambda: folders.SegmentationFolder,
                                      "RenderDataset": lambda: render_output.RenderDataset})
