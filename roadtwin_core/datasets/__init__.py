"""Dataset readers, side by side: labelled segmentation folders, real or rendered (``folders``),
and a ``roadtwin render`` output with every modality (``render_output``). numpy + Pillow only;
torch is imported when a ``Dataset`` class is first used."""
from .folders import (IGNORE_INDEX, IMAGE_SUFFIXES, Sample, find_pairs, load_folder, read_image, read_label,
                      read_sample)

__all__ = ["IGNORE_INDEX", "IMAGE_SUFFIXES", "Sample", "SegmentationFolder", "RenderDataset", "find_pairs",
           "load_folder", "read_image", "read_label", "read_sample"]


def __getattr__(name):  # the torch classes load on first use
    if name == "SegmentationFolder":
        from .folders import SegmentationFolder
        return SegmentationFolder
    if name == "RenderDataset":
        from .render_output import RenderDataset
        return RenderDataset
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
