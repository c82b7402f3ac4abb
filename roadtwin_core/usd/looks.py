"""The looks layer: ``UsdPreviewSurface`` materials over the textures written next to the stage,
bound to road segments, defect pieces and markings, plus the root's ``roadMaterial`` variant set.

Every material has the same small network, which roadtwin's renderer, Blender, usdview and
Isaac Sim all read (so keep it exactly so)::

    /<root>/Looks/<name>                  Material, outputs:surface <- PreviewSurface.outputs:surface
        PreviewSurface  UsdPreviewSurface  diffuseColor <- Diffuse.rgb, roughness <- Roughness.r
                                           (or a constant), normal <- Normal.rgb, metallic constant
        TexCoord        UsdPrimvarReader_float2, varname "st" (string)
        Diffuse         UsdUVTexture, sRGB, repeat, st <- TexCoord.result
        Roughness       UsdUVTexture, raw                      (only with a roughness map)
        Normal          UsdUVTexture, raw, scale (2,2,2,1), bias (-1,-1,-1,0)  (only with a normal map)

Texture paths are relative to this layer (``@../textures/<file>@``; a photo-made defect's decal
reads the town's copy of its library asset, ``@../library/textures/<file>@``), so the output folder
can move. Bindings are overs (``MaterialBindingAPI``) on prims other layers define. Driving and
junction surfaces are bound only inside the ``roadMaterial`` variants: a direct opinion in this
layer would be stronger than any variant (LIVRPS) and the switch would do nothing.
"""
from __future__ import annotations


from pxr import Sdf, Usd, UsdGeom, UsdShade

from ..errors import RoadtwinError
from ..looks.catalog import MaterialSpec

ROAD_MATERIAL_SET = "roadMaterial"
TEXTURE_DIR = "../textures"  # relative to layers/looks.usda

Binding = tuple[str, str]  # (prim path, material name)


def material_path(root: str, name: str) -> str:
    return f"{root}/Looks/{name}"


def _texture(stage: Usd.Stage, path: str, file: str, color_space: str, st: UsdShade.Shader,
             texture_dir: str, wrap: str) -> UsdShade.Shader:
    tex = UsdShade.Shader.Define(stage, path)
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"{texture_dir}/{file}"))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(wrap)
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wrap)
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st.ConnectableAPI(), "result")
    return tex


def define_material(stage: Usd.Stage, root: str, spec: MaterialSpec, texture_dir: str = TEXTURE_DIR) -> UsdShade.Material:
    """One material with the network of the module docstring (``<root>/Looks/<name>``; texture
    files under ``texture_dir``, relative to the layer that holds the material)."""
    path = material_path(root, spec.name)
    mat = UsdShade.Material.Define(stage, path)
    if spec.doc:
        mat.GetPrim().SetDocumentation(spec.doc)
    surface = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    surface.CreateIdAttr("UsdPreviewSurface")
    mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, f"{path}/TexCoord")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    # string, not token: the Sdr definition of UsdPrimvarReader says string since USD 21.11 and
    # pxr.UsdValidation's ShaderSdrCompliance rejects a token (Blender and usdview read both).
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)

    diffuse = _texture(stage, f"{path}/Diffuse", spec.diffuse, "sRGB", reader, texture_dir, spec.wrap)
    diffuse.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(diffuse.ConnectableAPI(), "rgb")
    if spec.opacity_from_alpha:
        diffuse.CreateOutput("a", Sdf.ValueTypeNames.Float)
        surface.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(diffuse.ConnectableAPI(), "a")
    roughness = surface.CreateInput("roughness", Sdf.ValueTypeNames.Float)
    if spec.roughness:
        tex = _texture(stage, f"{path}/Roughness", spec.roughness, "raw", reader, texture_dir, spec.wrap)
        tex.CreateOutput("r", Sdf.ValueTypeNames.Float)
        roughness.ConnectToSource(tex.ConnectableAPI(), "r")
    else:
        roughness.Set(float(spec.roughness_value))
    if spec.normal:
        tex = _texture(stage, f"{path}/Normal", spec.normal, "raw", reader, texture_dir, spec.wrap)
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set((2.0, 2.0, 2.0, 1.0))
        tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set((-1.0, -1.0, -1.0, 0.0))
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surface.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(float(spec.metallic))
    surface.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    return mat


def _bind(layer: Sdf.Layer, root: str, bindings: list[Binding], known: set[str], prefix: Sdf.Path | None = None) -> None:
    """What ``MaterialBindingAPI.Apply(prim).Bind(material)`` writes, at the Sdf level: an over
    applying the API with an explicit ``material:binding`` target (under ``prefix``, a variant)."""
    for prim_path, name in bindings:
        if name not in known:
            raise RoadtwinError(f"material {name!r} bound to {prim_path} was not written by the texture generator "
                                f"(known: {', '.join(sorted(known))})")
        path = Sdf.Path(prim_path)
        if prefix is not None:
            path = path.ReplacePrefix(path.GetPrefixes()[0], prefix)
        spec = Sdf.CreatePrimInLayer(layer, path)
        ops = spec.GetInfo("apiSchemas")
        spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=list(ops.prependedItems) + ["MaterialBindingAPI"]))
        rel = Sdf.RelationshipSpec(spec, UsdShade.Tokens.materialBinding, False)
        rel.targetPathList.explicitItems = [Sdf.Path(material_path(root, name))]


def write_looks(layer: Sdf.Layer, root: str, specs: dict[str, MaterialSpec], bindings: list[Binding],
                variants: dict[str, list[Binding]], default_variant: str,
                texture_dirs: dict[str, str] | None = None) -> None:
    """Materials (sorted by name), direct bindings, then the ``roadMaterial`` variant set on the
    root prim with its own bindings per variant (``default_variant`` selected). ``texture_dirs``:
    material name -> its texture folder relative to ``layer``, where not ``TEXTURE_DIR``.

    The few materials go through the UsdShade API on a stage opened for them alone; the bindings
    (one per segment, defect piece and marking: tens of thousands) are authored at the Sdf level
    in one change block once that stage is gone, so nothing recomposes after each edit."""
    stage = Usd.Stage.Open(layer)
    UsdGeom.Scope.Define(stage, f"{root}/Looks")
    for name in sorted(specs):
        define_material(stage, root, specs[name], (texture_dirs or {}).get(name, TEXTURE_DIR))
    del stage
    known = set(specs)
    with Sdf.ChangeBlock():
        _bind(layer, root, bindings, known)
        if variants:
            top = layer.GetPrimAtPath(root)
            vset = Sdf.VariantSetSpec(top, ROAD_MATERIAL_SET)
            top.variantSetNameList.prependedItems = [ROAD_MATERIAL_SET]
            for variant in variants:
                Sdf.VariantSpec(vset, variant)
                _bind(layer, root, variants[variant], known, Sdf.Path(root).AppendVariantSelection(ROAD_MATERIAL_SET, variant))
            top.variantSelections[ROAD_MATERIAL_SET] = default_variant


__all__ = ["ROAD_MATERIAL_SET", "define_material", "material_path", "write_looks"]
