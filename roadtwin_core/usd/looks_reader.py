"""Bound ``UsdPreviewSurface`` materials and texture coordinates of a stage's meshes, as plain data.

What a renderer needs of a look, read generically (any prim names; connections are followed
through node graphs with ``GetValueProducingAttributes``):

- ``inputs:diffuseColor``: a constant (linear) or a ``UsdUVTexture`` output (``rgb``, or one
  channel ``r``/``g``/``b``/``a`` as grey);
- ``inputs:roughness``: a constant or one channel of a ``UsdUVTexture``;
- ``inputs:normal``: optionally a ``UsdUVTexture`` ``rgb`` (tangent space, usually scale 2,
  bias -1);
- ``inputs:metallic``: a constant (a texture is refused: nothing roadtwin writes needs one).

Per texture: ``inputs:file`` resolved against the layer that authored it, ``scale``/``bias``
(applied after colour decoding, as the UsdPreviewSurface spec says), ``fallback`` (used when
``inputs:file`` is empty), ``wrapS``/``wrapT`` and ``sourceColorSpace``; ``auto`` means sRGB
for diffuse colour and raw for roughness and normals (what 8-bit PNG writers mean, and what
usdview/Blender assume). ``inputs:st`` names the primvar through a ``UsdPrimvarReader_float2``
(``inputs:varname``, default ``st``). A ``UsdTransform2d`` between reader and texture is refused
(the st convention needs none).

Bad looks are errors naming the material: a texture file that does not exist, a surface that is
not a ``UsdPreviewSurface``, a textured material on a mesh without the st primvar. A mesh with
no bound material gets ``None`` here and a neutral grey from the renderer.
"""
from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image
from pxr import Sdf, UsdGeom, UsdShade

from ..errors import RoadtwinError
from .stage import fan_corners

_CHANNELS = {"rgb": (0, 1, 2), "rgba": (0, 1, 2), "r": (0,), "g": (1,), "b": (2,), "a": (3,)}
_WRAPS = ("repeat", "clamp", "mirror", "black", "useMetadata")


@dataclass(frozen=True)
class TextureRef:
    """One ``UsdUVTexture`` as used by one material input."""

    path: str                         # resolved file path ("" = no file: ``fallback`` everywhere)
    channels: tuple[int, ...]         # image channels the connected output reads
    srgb: bool                        # decode sRGB -> linear before scale/bias
    scale: tuple[float, ...]          # per channel of ``channels`` (after decoding)
    bias: tuple[float, ...]
    fallback: tuple[float, ...]
    wrap_s: str = "repeat"
    wrap_t: str = "repeat"


@dataclass(frozen=True)
class TownMaterial:
    """A bound material, resolved: constants where no texture is connected."""

    name: str                                   # material prim path
    diffuse_color: tuple[float, float, float] = (0.18, 0.18, 0.18)   # linear
    diffuse_texture: TextureRef | None = None
    roughness: float = 0.5
    roughness_texture: TextureRef | None = None
    normal_texture: TextureRef | None = None
    metallic: float = 0.0
    st_name: str = "st"                         # primvar the textures read

    @property
    def textured(self) -> bool:
        return any((self.diffuse_texture, self.roughness_texture, self.normal_texture))


# ------------------------------------------------------------------------------------ materials
def bound_material(prim, cache: dict) -> TownMaterial | None:
    """The prim's bound material (full purpose), parsed once per material path."""
    mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not mat:
        return None
    key = str(mat.GetPath())
    if key not in cache:
        cache[key] = parse_material(mat)
    return cache[key]


def parse_material(mat: UsdShade.Material) -> TownMaterial:
    name = str(mat.GetPath())
    shader, _, _ = mat.ComputeSurfaceSource()
    if not shader:
        raise RoadtwinError(f"material {name}: no surface shader (outputs:surface is not connected)")
    sid = shader.GetIdAttr().Get() if shader.GetIdAttr() else None
    if sid != "UsdPreviewSurface":
        raise RoadtwinError(f"material {name}: surface shader {shader.GetPath()} is {sid!r}, "
                            "roadtwin renders UsdPreviewSurface only")
    st_names: list[str] = []
    out: dict = {"name": name}
    for key, inp_name, kind in (("diffuse", "diffuseColor", "color"), ("roughness", "roughness", "scalar"),
                                ("normal", "normal", "normal"), ("metallic", "metallic", "scalar")):
        value, tex = _input(shader, inp_name, name, kind, st_names)
        if key == "diffuse":
            if value is not None:
                out["diffuse_color"] = tuple(float(x) for x in np.asarray(value, float).reshape(3))
            out["diffuse_texture"] = tex
        elif key == "roughness":
            if value is not None:
                out["roughness"] = float(value)
            out["roughness_texture"] = tex
        elif key == "normal":
            out["normal_texture"] = tex
        else:
            if tex is not None:
                raise RoadtwinError(f"material {name}: a metallic texture is not supported (use a constant)")
            if value is not None:
                out["metallic"] = float(value)
    if len(set(st_names)) > 1:
        raise RoadtwinError(f"material {name}: textures read different primvars {sorted(set(st_names))}")
    if st_names:
        out["st_name"] = st_names[0]
    return TownMaterial(**out)


def _source(inp: UsdShade.Input):
    """(value attribute or None, (shader, output name) or None), following connections."""
    attrs = inp.GetValueProducingAttributes()
    if not attrs:
        return None, None
    a = attrs[0]
    if UsdShade.Utils.GetType(a.GetName()) == UsdShade.AttributeType.Output:
        return None, (UsdShade.Shader(a.GetPrim()), UsdShade.Utils.GetBaseNameAndType(a.GetName())[0])
    return a, None


def _input(shader: UsdShade.Shader, input_name: str, mat: str, kind: str, st_names: list):
    inp = shader.GetInput(input_name)
    if not inp:
        return None, None
    attr, src = _source(inp)
    if src is None:
        return (attr.Get() if attr is not None and attr.HasValue() else None), None
    tex_shader, output = src
    sid = tex_shader.GetIdAttr().Get() if tex_shader.GetIdAttr() else None
    if sid != "UsdUVTexture":
        raise RoadtwinError(f"material {mat}: inputs:{input_name} comes from {tex_shader.GetPath()} ({sid!r}); "
                            "only constants and UsdUVTexture are supported")
    channels = _CHANNELS.get(output)
    if channels is None:
        raise RoadtwinError(f"material {mat}: {tex_shader.GetPath()} has no output {output!r}")
    if kind in ("color", "normal") and len(channels) == 1:
        channels = channels * 3                  # a grey channel drives all three
    if kind == "scalar" and len(channels) != 1:
        channels = channels[:1]

    def value(name, default):
        i = tex_shader.GetInput(name)
        if not i:
            return default
        a, s = _source(i)
        if s is not None:
            raise RoadtwinError(f"material {mat}: {tex_shader.GetPath()}.inputs:{name} is connected; "
                                "roadtwin reads it as a constant only")
        return a.Get() if a is not None and a.HasValue() else default

    file_in = tex_shader.GetInput("file")
    path = ""
    if file_in:
        attr, _ = _source(file_in)
        asset = attr.Get() if attr is not None else None
        if isinstance(asset, Sdf.AssetPath) and asset.path:
            path = asset.resolvedPath or ""
            if not path or not os.path.isfile(path):
                raise RoadtwinError(f"material {mat}: texture file {asset.path!r} of {tex_shader.GetPath()} "
                                    "does not exist")
    space = str(value("sourceColorSpace", "auto"))
    srgb = space == "sRGB" or (space == "auto" and kind == "color")
    sel = [c if c < 4 else 0 for c in channels]
    scale4 = np.asarray(value("scale", (1.0, 1.0, 1.0, 1.0)), float).reshape(4)
    bias4 = np.asarray(value("bias", (0.0, 0.0, 0.0, 0.0)), float).reshape(4)
    fb4 = np.asarray(value("fallback", (0.0, 0.0, 0.0, 1.0)), float).reshape(4)
    wrap_s, wrap_t = str(value("wrapS", "useMetadata")), str(value("wrapT", "useMetadata"))
    for w in (wrap_s, wrap_t):
        if w not in _WRAPS:
            raise RoadtwinError(f"material {mat}: {tex_shader.GetPath()} has an unknown wrap mode {w!r}")
    st_in = tex_shader.GetInput("st")
    if st_in:
        _, st_src = _source(st_in)
        if st_src is not None:
            reader = st_src[0]
            rid = reader.GetIdAttr().Get() if reader.GetIdAttr() else None
            if rid != "UsdPrimvarReader_float2":
                raise RoadtwinError(f"material {mat}: st of {tex_shader.GetPath()} comes from {reader.GetPath()} "
                                    f"({rid!r}); only UsdPrimvarReader_float2 is supported")
            vn = reader.GetInput("varname")
            name = None
            if vn:
                a, _ = _source(vn)
                name = a.Get() if a is not None and a.HasValue() else None
            st_names.append(str(name) if name else "st")
    tex = TextureRef(path, tuple(sel), srgb, tuple(scale4[sel].tolist()), tuple(bias4[sel].tolist()),
                     tuple(fb4[sel].tolist()), wrap_s, wrap_t)
    return None, tex


# ------------------------------------------------------------------------------------ st
def corner_st(mesh: UsdGeom.Mesh, name: str, counts: np.ndarray) -> np.ndarray | None:
    """Primvar ``name`` per triangle corner, (M, 3, 2) float32, for the fan triangulation that
    :func:`roadtwin_core.usd.stage.read_mesh` uses; None when the mesh has no such primvar."""
    pv = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar(name)
    if not pv or not pv.HasValue():
        return None
    vals = pv.ComputeFlattened()
    if vals is None:
        return None
    vals = np.asarray(vals, dtype=np.float32).reshape(-1, 2)
    tri_face, corners = fan_corners(counts)                           # face-vertex (corner) indices
    interp = pv.GetInterpolation()
    if interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64)
        sel = idx[corners]
    elif interp == UsdGeom.Tokens.faceVarying:
        sel = corners
    elif interp == UsdGeom.Tokens.uniform:
        sel = np.repeat(tri_face[:, None], 3, axis=1)
    else:                                                            # constant
        sel = np.zeros_like(corners)
    if len(sel) and sel.max() >= len(vals):
        raise RoadtwinError(f"{mesh.GetPath()}: primvars:{name} has {len(vals)} values, too few for "
                            f"{interp} interpolation")
    return vals[sel]


# ------------------------------------------------------------------------------------ images
_IMAGES: "OrderedDict[tuple, np.ndarray]" = OrderedDict()
_IMAGE_CACHE_SIZE = 48


def texture_image(path: str | Path) -> np.ndarray:
    """A texture file as float32 (H, W, 4) in [0, 1] (not colour-decoded), cached by path and
    modification time (a file replaced in place is read again)."""
    st = os.stat(path)
    key = (str(path), st.st_mtime_ns, st.st_size)
    img = _IMAGES.get(key)
    if img is not None:
        _IMAGES.move_to_end(key)
        return img
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.float32) / 65535.0
                a = np.repeat(a[..., None], 3, axis=2)
                a = np.concatenate([a, np.ones_like(a[..., :1])], axis=2)
            else:
                a = np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0
    except Exception as exc:
        raise RoadtwinError(f"{path}: not a readable image ({exc})") from None
    a = np.ascontiguousarray(a)
    _IMAGES[key] = a
    while len(_IMAGES) > _IMAGE_CACHE_SIZE:
        _IMAGES.popitem(last=False)
    return a


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def decode_texture(tex: TextureRef) -> np.ndarray:
    """The texture's values as the shader sees them: (H, W, len(channels)) float32, colour
    decoded, then ``* scale + bias``; a 1x1 image of ``fallback`` when there is no file."""
    if not tex.path:
        return np.asarray(tex.fallback, np.float32).reshape(1, 1, -1)
    img = texture_image(tex.path)[..., list(tex.channels)]
    if tex.srgb:
        rgb = [i for i, c in enumerate(tex.channels) if c < 3]
        img = img.copy()
        img[..., rgb] = srgb_to_linear(img[..., rgb])
    return (img * np.asarray(tex.scale, np.float32) + np.asarray(tex.bias, np.float32)).astype(np.float32)
