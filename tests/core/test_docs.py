"""The docs cannot silently fall behind the code.

docs/plugins.md: every hook in ``roadtwin_core/hookspecs.py`` has a section there, and every
protocol in ``roadtwin_core/contracts.py`` is named in it. Each section names its protocol's
attributes and methods, and each section's example is a plugin module that registers through the
plugin manager and meets its contract. The cheap examples are also run once.

docs/architecture.md: every ``docs/architecture.md#<section>`` that code, tests or docs cite is a
heading of that page, and nothing cites a design document outside the repository.
"""
from __future__ import annotations

import inspect
import re
import sys
import types
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from roadtwin_core import ComposeRules, DefectModel, FlatSurface, MergedSegment, RoadSegment, SurfaceModel, TownLayout, \
    contracts, hookspecs
from roadtwin_core.plugins import KINDS, PluginManager
from roadtwin_core.render import Camera, Frame, Intrinsics

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "plugins.md"
ARCHITECTURE = REPO / "docs" / "architecture.md"
SOURCES = ("README.md", "docs", "roadtwin_core", "plugins", "tests", "bench", "stages")
PREFIX = "roadtwin_register_"


def hook_names() -> list[str]:
    return sorted(name for name, f in vars(hookspecs).items() if callable(f) and hasattr(f, "roadtwin_spec"))


def protocols() -> dict[str, type]:
    return {name: c for name, c in vars(contracts).items()
            if inspect.isclass(c) and c.__module__ == contracts.__name__ and getattr(c, "_is_protocol", False)}


def members(protocol: type) -> list[str]:
    """The attributes and public methods a protocol declares."""
    return [*getattr(protocol, "__annotations__", {}),
            *(n for n, f in vars(protocol).items() if inspect.isfunction(f) and not n.startswith("_"))]


def section(hook: str) -> str:
    """The text of a hook's section: from its ``### hook`` heading to the next heading."""
    text = DOC.read_text()
    found = re.search(rf"^### {hook}\n(.*?)(?=^#{{1,3}} |\Z)", text, re.S | re.M)
    assert found, f"docs/plugins.md has no section '### {hook}'"
    return found.group(1)


def example(hook: str) -> types.ModuleType:
    """A section's one python block, run as a module of its own (as an installed plugin would be)."""
    blocks = re.findall(r"^```python\n(.*?)^```", section(hook), re.S | re.M)
    assert len(blocks) == 1, f"{hook}: expected one python example, found {len(blocks)}"
    name = f"plugins_md_{hook.removeprefix(PREFIX)}"
    module = types.ModuleType(name)
    sys.modules[name] = module  # dataclasses and pickle look the module up by name
    exec(compile(blocks[0], f"docs/plugins.md ({hook})", "exec"), module.__dict__)
    return module


def test_every_hook_and_protocol_is_named():
    text = DOC.read_text()
    assert [f"{PREFIX}{k}" for k in sorted(KINDS)] == hook_names()
    assert set(protocols()) == {p.__name__ for p in contracts.PROTOCOLS.values()}
    missing = [n for n in [*hook_names(), *protocols(), "RendererBase"] if n not in text]
    assert not missing, f"docs/plugins.md does not name: {missing}"


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_each_hook_section_names_its_protocol_and_members(kind):
    text = section(f"{PREFIX}{kind}")
    protocol = contracts.PROTOCOLS[kind]
    assert f"`{protocol.__name__}`" in text
    missing = [m for m in members(protocol) if f"`{m}" not in text]
    assert not missing, f"the {PREFIX}{kind} section does not name {protocol.__name__}'s {missing}"


@pytest.fixture(scope="module")
def examples():
    modules = {kind: example(f"{PREFIX}{kind}") for kind in KINDS}
    yield modules
    for m in modules.values():
        sys.modules.pop(m.__name__, None)


@pytest.fixture(scope="module")
def pm(examples):
    manager = PluginManager(load_entry_points=False)
    for kind, module in examples.items():
        manager.register(module, name=f"example_{kind}")
    return manager


def test_every_example_registers_and_meets_its_contract(pm):
    info = pm.load_all()
    errors = {name: i.error for name, i in info.items() if i.error}
    assert not errors, errors
    for kind in KINDS:
        assert list(info[f"example_{kind}"].registered) == [kind]
        assert len(pm.registry(kind)) == 1


def test_the_cheap_examples_run(pm, tmp_path):
    dent = pm.get("defect_types", "pyramid_dent")
    model = dent.generate(dent.sample_params(np.random.default_rng(0)), np.random.default_rng(0), "d")
    assert isinstance(model, DefectModel) and model.depth_m > 0

    surface = pm.get("surface_sources", "tilted").load("0.02", (0.0, 0.0, 10.0, 10.0), 0)
    assert isinstance(surface, SurfaceModel)
    np.testing.assert_allclose(surface.height(np.array([[5.0, 1.0]])), [0.1])

    (tmp_path / "roads.txt").write_text("a driving 0 0 20 3.5\nb sidewalk 0 3.5 20 5\n")
    layout = pm.get("layout_importers", "rectangles").load(tmp_path / "roads.txt", None)
    assert isinstance(layout, TownLayout) and [s.kind for s in layout.segments] == ["driving", "sidewalk"]

    merged = pm.get("mergers", "lift_only").merge(layout.segments[0], [], surface, ComposeRules())
    assert isinstance(merged, MergedSegment) and (merged.face_owner == -1).all()
    np.testing.assert_allclose(merged.vertices[:, 2], 0.02 * merged.vertices[:, 0])

    points = np.random.default_rng(0).uniform(0, 4, (400, 3)) * [1, 1, 0.01]
    np.save(tmp_path / "frame.npy", points)
    rec = pm.get("reconstructors", "points_surface")
    result = rec.run({"frames": [tmp_path / "frame.npy"]}, rec.Params())
    written = rec.write(result, tmp_path / "surface.usda")
    stage = Usd.Stage.Open(str(written))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Surface/mesh"))
    assert len(mesh.GetPointsAttr().Get()) == len(result.vertices)

    camera = Camera(Intrinsics.from_fov(8, 6), np.eye(4))
    frames = list(pm.get("renderers", "blank").render(None, [camera, camera], None))
    assert [f.index for f in frames] == [0, 1] and frames[0].depth.shape == (6, 8)

    (tmp_path / "render").mkdir()
    writer = pm.get("dataset_formats", "instance_pixels").writer(SimpleNamespace(root=tmp_path / "render"))
    frame = Frame(index=0, camera=camera, instance=np.array([[0, 1], [1, 2]], np.int32))
    files = {}
    assert writer.add(0, "000000", frame, files) == {"defect_instances_seen": 2}
    writer.finish()
    assert (tmp_path / "render" / files["instance_pixels"]).read_text() == '{"1": 2, "2": 1}'

    sensor = pm.get("sensors", "ideal_imu")
    imu = sensor.create("imu", 200.0, np.eye(4), sensor.Params())
    state = SimpleNamespace(t=0.5, pose_at=lambda t: np.eye(4),
                            imu_truth=lambda offset, t0, t1: (np.array([0.0, 0.0, 9.81]), np.array([0.0, 0.0, 0.1])))
    sample = imu.sample(state, None)
    np.testing.assert_allclose(sample["linear_acceleration"], [0.0, 0.0, 9.81])
    np.testing.assert_allclose(sample["angular_velocity"], [0.0, 0.0, 0.1])
    np.testing.assert_allclose(sample["orientation"], [0.0, 0.0, 0.0, 1.0])


# ---- docs/architecture.md ---------------------------------------------------------------------

def anchors(markdown: str) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces -> '-'."""
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-")
            for h in re.findall(r"^#+ (.+)$", markdown, re.M)}


def text_files():
    for top in SOURCES:
        path = REPO / top
        for f in [path] if path.is_file() else sorted(path.rglob("*")):
            if f.suffix in (".py", ".md", ".toml") and "__pycache__" not in f.parts:
                yield f


def test_architecture_citations_point_to_existing_sections():
    known = anchors(ARCHITECTURE.read_text())
    cited = {(f.relative_to(REPO).as_posix(), a) for f in text_files()
             for a in re.findall(r"architecture\.md#([\w-]+)", f.read_text())}
    assert len(cited) >= 5  # code and tests do cite it
    broken = sorted((f, a) for f, a in cited if a not in known)
    assert not broken, f"citations of missing docs/architecture.md sections: {broken}"


def test_nothing_cites_a_design_document_outside_the_repository():
    outside = "DESIGN" + ".md"  # spelled apart so this file does not cite it
    citing = [f.relative_to(REPO).as_posix() for f in text_files() if outside in f.read_text()]
    assert not citing, f"{outside} is not in the repository; cite docs/architecture.md instead: {citing}"
