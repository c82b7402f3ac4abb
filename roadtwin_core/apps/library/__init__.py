"""``roadtwin library``: a folder of defect library assets, listed, shown and added to.

A library folder holds ``NAME.usda`` (or ``.usd`` / ``.usdc``) interface files (labels,
``roadtwin:defect:*`` attributes, extent) that payload ``NAME.geom.usda``
(:mod:`roadtwin_core.usd.library`, whose :func:`~roadtwin_core.usd.library.is_asset_file` is the
one rule for which files are assets, shared with ``compose --library``); a composed town's
``OUT/library/`` is one. ``read`` reads interfaces without loading geometry (list, show);
``add`` copies a validated asset in atomically.
"""
from .add import add_asset
from .read import (AssetDetails, AssetInterface, asset_files, find_asset, library_folder, list_assets, read_interface,
                   show_asset)

__all__ = ["AssetDetails", "AssetInterface", "add_asset", "asset_files", "find_asset", "library_folder", "list_assets",
           "read_interface", "show_asset"]
