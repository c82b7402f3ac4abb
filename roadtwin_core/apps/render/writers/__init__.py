"""Dataset writers of ``roadtwin render``: ``DatasetWriter`` writes what every render has and
dispatches each frame to the writers of the chosen formats, found by name in ``WRITERS``."""
from .coco import rle_decode, rle_encode
from .dataset import DatasetWriter
from .registry import FORMATS, WRITERS, available_formats, parse_formats

__all__ = ["DatasetWriter", "FORMATS", "WRITERS", "available_formats", "parse_formats", "rle_decode", "rle_encode"]
