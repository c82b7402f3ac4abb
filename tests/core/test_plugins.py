"""The plugin manager and typed parameters.

Entry points are faked by replacing ``importlib.metadata.entry_points`` (the function
``roadtwin_core.plugins`` calls) so these tests do not depend on which built-in plugins exist yet.
"""
from __future__ import annotations

import dataclasses
import importlib.metadata
import math
import types

import numpy as np

import pytest

from roadtwin_core import RoadtwinError, field, hookimpl, make_params
from roadtwin_core import plugins as plugins_mod
from roadtwin_core.plugins import ALLOW_ENV, ENTRY_POINT_GROUP, KINDS, PluginManager


# --------------------------------------------------------------------------- helpers
@dataclasses.dataclass
class NoParams:
    pass


class Thing:
    """The least a registered thing of any kind needs: written from the contract's prose, one
    method stub per kind (a thing of another kind carries harmless extra names)."""

    Params = NoParams
    params = NoParams()
    produces = "surface"
    suffix = ".x"
    needs_stereo = False

    def __init__(self, name: str, description: str = "") -> None:
        self.name = name
        self.description = description

    def sample_params(self, rng): return NoParams()
    def generate(self, params, rng, name): return None
    def run(self, inputs, params): return None
    def write(self, result, out): return out
    def merge(self, segment, placements, surface, rules): return None
    def load(self, *args): return None  # layout importers (path, params), surface sources (arg, bounds, seed)
    def render(self, scene, cameras, params, look=None): return iter(())
    def prepare(self, scene, params): return scene
    def check_cameras(self, prepared, cameras, params): return None
    def render_events(self, scene, cameras, times, params, progress=None, threshold=0.2, seed=0): return None
    def simulate(self, road_mesh, vehicles, params): return None
    def plan(self, grid, start, goal, vehicle, collision, params, rng): return None
    def export(self, stage_path, out_path): return out_path
    def writer(self, dataset): return None


def plugin_module(modname: str, **hooks) -> types.ModuleType:
    """A module object whose hooks register ``Thing``s: kind=[names] or kind=Exception."""
    mod = types.ModuleType(modname)
    for kind, spec in hooks.items():
        def impl(register, _spec=spec):
            if isinstance(_spec, BaseException):
                raise _spec
            for n in _spec:
                register(Thing(n) if isinstance(n, str) else n)
        impl.__name__ = f"roadtwin_register_{kind}"
        setattr(mod, impl.__name__, hookimpl(impl))
    return mod


class FakeEntryPoint:
    """Quacks like importlib.metadata.EntryPoint: name, dist, load()."""

    def __init__(self, name: str, target=None, error: BaseException | None = None,
                 version: str = "9.9") -> None:
        self.name, self.group, self._target, self._error = name, ENTRY_POINT_GROUP, target, error
        self.dist = types.SimpleNamespace(version=version)
        self.loaded = False

    def load(self):
        self.loaded = True
        if self._error is not None:
            raise self._error
        return self._target


@pytest.fixture
def fake_eps(monkeypatch):
    """Install a list of fake entry points; returns a setter."""
    monkeypatch.delenv(ALLOW_ENV, raising=False)

    def install(*eps):
        def entry_points(**kw):
            assert kw == {"group": ENTRY_POINT_GROUP}
            return list(eps)
        monkeypatch.setattr(plugins_mod.importlib.metadata, "entry_points", entry_points)
        return eps
    return install


# --------------------------------------------------------------------------- real entry points
def test_builtin_entry_points_are_read(monkeypatch):
    """With the project installed, its entry-point group lists the built-ins and every one
    of them shows up in ``info`` (loaded, or with its error: packages may still be empty)."""
    monkeypatch.delenv(ALLOW_ENV, raising=False)
    declared = {ep.name for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}
    assert {"defects", "cdt", "export"} <= declared
    pm = PluginManager()
    assert declared <= set(pm.info)
    for name in ("defects", "cdt", "export"):
        assert pm.info[name].name == name
    info = pm.load_all()  # never raises, whatever state the plugins are in
    assert set(info) >= declared


def test_no_entry_points_when_asked():
    pm = PluginManager(load_entry_points=False)
    assert pm.info == {}
    assert pm.load_all() == {}
    for kind in KINDS:
        assert pm.registry(kind) == {}


# --------------------------------------------------------------------------- fake plugins
def test_failing_import_is_reported_and_others_work(fake_eps):
    good = plugin_module("fake_good", exporters=["glb", "obj"])
    fake_eps(FakeEntryPoint("broken", error=ImportError("no module named 'warp'")),
             FakeEntryPoint("good", good, version="1.2.3"),
             FakeEntryPoint("crashy", error=ZeroDivisionError("division by zero")))
    pm = PluginManager()
    assert pm.info["broken"].error == "ImportError: no module named 'warp'"
    assert pm.info["crashy"].error == "ZeroDivisionError: division by zero"
    assert pm.info["good"].error == ""
    assert pm.info["good"].version == "1.2.3"
    assert sorted(pm.registry("exporters")) == ["glb", "obj"]
    assert pm.get("exporters", "glb").name == "glb"
    info = pm.load_all()
    assert info["good"].registered == {"exporters": ["glb", "obj"]}
    assert info["broken"].registered == {}


def test_entry_point_with_missing_module(fake_eps):
    """A real EntryPoint whose module cannot be imported."""
    ep = importlib.metadata.EntryPoint(name="ghost", value="roadtwin_no_such_plugin_xyz",
                                       group=ENTRY_POINT_GROUP)
    fake_eps(ep, FakeEntryPoint("good", plugin_module("fake_good2", planners=["astar"])))
    pm = PluginManager()
    assert "ModuleNotFoundError" in pm.info["ghost"].error
    assert "roadtwin_no_such_plugin_xyz" in pm.info["ghost"].error
    assert list(pm.registry("planners")) == ["astar"]


def test_hook_that_raises_is_recorded(fake_eps):
    bad = plugin_module("fake_bad", defect_types=RuntimeError("bad table"), exporters=["ply"])
    good = plugin_module("fake_ok", defect_types=["pothole", "crack"])
    fake_eps(FakeEntryPoint("bad", bad), FakeEntryPoint("ok", good))
    pm = PluginManager()
    things = pm.registry("defect_types")
    assert sorted(things) == ["crack", "pothole"]
    assert pm.info["bad"].error == "defect_types: RuntimeError: bad table"
    assert pm.info["ok"].error == ""
    # the failing plugin's other hooks still register
    assert list(pm.registry("exporters")) == ["ply"]
    info = pm.load_all()
    assert info["ok"].registered == {"defect_types": ["pothole", "crack"]}
    assert info["bad"].registered == {"exporters": ["ply"]}


def test_duplicate_name_names_the_first_plugin(fake_eps):
    fake_eps(FakeEntryPoint("alpha", plugin_module("fake_a", mergers=["cdt", "boolean"])),
             FakeEntryPoint("beta", plugin_module("fake_b", mergers=["cdt", "voxel"])))
    pm = PluginManager()
    mergers = pm.registry("mergers")
    assert sorted(mergers) == ["boolean", "cdt", "voxel"]
    # whichever plugin registered 'cdt' first keeps it; the other carries the error naming it
    winner = next(n for n in ("alpha", "beta") if "cdt" in pm.info[n].registered.get("mergers", []))
    loser = "beta" if winner == "alpha" else "alpha"
    assert "cdt" not in pm.info[loser].registered.get("mergers", [])
    err = pm.info[loser].error
    assert "'cdt'" in err and repr(winner) in err and "mergers" in err
    assert pm.info[winner].error == ""
    assert mergers["cdt"] is not None


def test_object_without_name_is_reported(fake_eps):
    nameless = types.SimpleNamespace(description="no name")
    fake_eps(FakeEntryPoint("odd", plugin_module("fake_odd", renderers=[nameless, "raster"])))
    pm = PluginManager()
    assert list(pm.registry("renderers")) == ["raster"]
    assert "without a name" in pm.info["odd"].error


def test_allow_list_restricts_loading(fake_eps, monkeypatch):
    eps = fake_eps(FakeEntryPoint("a", plugin_module("fake_al_a", planners=["pa"])),
                   FakeEntryPoint("b", plugin_module("fake_al_b", planners=["pb"])),
                   FakeEntryPoint("c", error=ImportError("never loaded")))
    monkeypatch.setenv(ALLOW_ENV, " b , ")
    pm = PluginManager()
    assert set(pm.info) == {"b"}
    assert list(pm.registry("planners")) == ["pb"]
    assert [ep.loaded for ep in eps] == [False, True, False]  # others not even imported

    monkeypatch.setenv(ALLOW_ENV, "")  # set but empty: nothing loads
    assert PluginManager().info == {}

    monkeypatch.delenv(ALLOW_ENV)
    assert set(PluginManager().info) == {"a", "b", "c"}


def test_one_plugin_found_by_what_it_provides_loads_alone(fake_eps, monkeypatch):
    """What the composer's preview helper does: ask which plugin provides renderer X, then load
    only that one (the others are not even imported); the user's allow-list still applies."""
    eps = fake_eps(FakeEntryPoint("a", plugin_module("fake_pr_a", planners=["pa"])),
                   FakeEntryPoint("b", plugin_module("fake_pr_b", renderers=["warp"])),
                   FakeEntryPoint("c", error=ImportError("never loaded")))
    full = PluginManager()
    assert full.provider("renderers", "warp") == "b"
    assert full.provider("renderers", "other") is None and full.provider("planners", "warp") is None
    for ep in eps:
        ep.loaded = False
    alone = PluginManager(only=("b",))
    assert set(alone.info) == {"b"} and list(alone.registry("renderers")) == ["warp"]
    assert [ep.loaded for ep in eps] == [False, True, False]
    monkeypatch.setenv(ALLOW_ENV, "a")
    assert PluginManager(only=("b",)).info == {}


def test_get_plugin_manager_is_shared_and_resettable(fake_eps):
    fake_eps(FakeEntryPoint("one", plugin_module("fake_one", exporters=["usdz"])))
    plugins_mod.reset_plugin_manager()
    try:
        pm = plugins_mod.get_plugin_manager()
        assert plugins_mod.get_plugin_manager() is pm
        assert set(pm.info) == {"one"}
        plugins_mod.reset_plugin_manager()
        assert plugins_mod.get_plugin_manager() is not pm
    finally:
        plugins_mod.reset_plugin_manager()


def test_get_unknown_lists_known_names():
    pm = PluginManager(load_entry_points=False)
    pm.register(plugin_module("fake_d", defect_types=["pothole", "bump"]), name="d")
    with pytest.raises(RoadtwinError) as exc:
        pm.get("defect_types", "sinkhole")
    msg = str(exc.value)
    assert "defect type" in msg and "'sinkhole'" in msg and "bump, pothole" in msg
    with pytest.raises(RoadtwinError, match=r"unknown physics backend 'x' \(known: none\)"):
        pm.get("physics_backends", "x")
    with pytest.raises(ValueError):
        pm.registry("no_such_kind")


def test_register_directly_then_recompute_does_not_duplicate():
    pm = PluginManager(load_entry_points=False)
    pm.register(plugin_module("fake_r1", exporters=["glb"]), name="r1", version="0.3")
    assert pm.load_all()["r1"].registered == {"exporters": ["glb"]}
    pm.register(plugin_module("fake_r2", exporters=["obj"]), name="r2")  # clears the cache
    info = pm.load_all()
    assert info["r1"].registered == {"exporters": ["glb"]}
    assert info["r1"].version == "0.3"
    assert sorted(pm.registry("exporters")) == ["glb", "obj"]


def test_every_problem_of_a_plugin_is_kept():
    pm = PluginManager(load_entry_points=False)
    pm.register(plugin_module("fake_p1", exporters=["glb"]), name="p1")
    pm.register(plugin_module("fake_p2", exporters=["glb"], planners=RuntimeError("x")), name="p2")
    pm.load_all()
    pm.load_all()
    errors = [e for n in ("p1", "p2") for e in pm.info[n].error.split("; ") if e]
    assert any("'glb' already registered" in e for e in errors)
    assert "planners: RuntimeError: x" in errors
    assert len(errors) == len(set(errors)) == 2  # recomputing does not repeat them


# --------------------------------------------------------------------------- params
@dataclasses.dataclass
class PotholeParams:
    depth_m: float = field(0.05, lo=0.0, hi=0.5, doc="depth below the surface")
    radius_m: float = field(0.3, lo=0.01)
    sides: int = field(12, lo=3)
    label: str = "pothole"
    flat_bottom: bool = False


def test_make_params_accepts_valid():
    p = make_params(PotholeParams, {"depth_m": 0.1, "sides": 7}, "pothole")
    assert (p.depth_m, p.radius_m, p.sides) == (0.1, 0.3, 7)
    assert make_params(PotholeParams, {}, "pothole") == PotholeParams()
    assert make_params(PotholeParams, {"depth_m": 0.0, "flat_bottom": True}, "pothole").flat_bottom


def test_make_params_rejects_unknown_keys():
    with pytest.raises(RoadtwinError) as exc:
        make_params(PotholeParams, {"depht_m": 0.1, "zz": 1}, "pothole")
    msg = str(exc.value)
    assert msg.startswith("pothole:") and "depht_m" in msg and "zz" in msg
    assert "depth_m" in msg  # lists the known names


@pytest.mark.parametrize("values,words", [
    ({"depth_m": math.nan}, ["depth_m", "finite"]),
    ({"radius_m": math.inf}, ["radius_m", "finite"]),
    ({"depth_m": -0.01}, ["depth_m", ">= 0.0"]),
    ({"radius_m": 0.0}, ["radius_m", ">= 0.01"]),
    ({"sides": 2}, ["sides", ">= 3"]),
    ({"depth_m": 0.6}, ["depth_m", "<= 0.5"]),
])
def test_make_params_rejects_bad_values(values, words):
    with pytest.raises(RoadtwinError) as exc:
        make_params(PotholeParams, values, "pothole")
    msg = str(exc.value)
    assert msg.startswith("pothole:")
    for w in words:
        assert w in msg, msg


# --------------------------------------------------------------------------- contracts
from roadtwin_core import contracts  # noqa: E402


def run_cli(monkeypatch, capsys, pm: PluginManager, *args: str) -> tuple[int, str, str]:
    """``roadtwin ARGS`` in this process with ``pm`` as the shared plugin manager."""
    import sys

    from roadtwin_core import cli

    monkeypatch.setattr(plugins_mod, "_manager", pm)
    monkeypatch.setattr(sys, "argv", ["roadtwin", *args])
    try:
        cli.main()
        code = 0
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


@dataclasses.dataclass
class HeightParams:
    voxel_m: float = field(0.05, lo=0.001)
    radius_m: float = field(0.08, lo=0.001)
    align: bool = True
    lift_m: float = field(0.0, lo=-1.0, hi=1.0, doc="added to every height")


class HeightmapReconstructor:
    """Written from the documented contract only (contracts.Reconstructor), no base class."""

    name = "heightmap"
    description = "test: one flat triangle per frame"
    produces = "surface"
    Params = HeightParams

    def __init__(self) -> None:
        self.calls = []

    def run(self, inputs, params):
        self.calls.append((inputs, params))
        z = params.lift_m
        return types.SimpleNamespace(vertices=np.array([[0, 0, z], [2, 0, z], [0, 3, z]], float),
                                     faces=np.array([[0, 1, 2]]))

    def write(self, result, out):
        out.write_text(f"{len(result.vertices)} {result.vertices[0, 2]}")
        return out


def contract_module(modname: str, **things) -> types.ModuleType:
    mod = types.ModuleType(modname)
    for kind, objs in things.items():
        def impl(register, _objs=objs):
            for o in _objs:
                register(o)
        impl.__name__ = f"roadtwin_register_{kind}"
        setattr(mod, impl.__name__, hookimpl(impl))
    return mod


def test_reconstructor_written_to_the_contract_runs_through_the_cli(tmp_path, monkeypatch, capsys):
    rec = HeightmapReconstructor()
    assert contracts.check("reconstructors", rec) == []
    pm = PluginManager(load_entry_points=False)
    pm.register(contract_module("fake_heightmap", reconstructors=[rec]), name="heightmap_plugin")
    frame = tmp_path / "f.npy"
    np.save(frame, np.zeros((4, 3)))
    out = tmp_path / "surface.usda"
    code, stdout, err = run_cli(monkeypatch, capsys, pm, "reconstruct", "surface", str(frame), "-o", str(out),
                                "--reconstructor", "heightmap", "--voxel", "0.1", "--param", "lift_m=0.25")
    assert code == 0, err
    (inputs, params), = rec.calls
    assert inputs["frames"] == [frame]
    assert (params.voxel_m, params.radius_m, params.lift_m) == (0.1, 0.08, 0.25)
    assert out.read_text() == "3 0.25"
    assert "3 vertices, 1 triangles, 2.00 x 3.00 m" in stdout


def test_old_reconstruct_only_contract_is_reported_and_others_load(fake_eps):
    class OldStyle:  # what hookspecs.py used to document: reconstruct(inputs, params) -> list
        name, description, produces, Params = "old", "reconstruct() only", "defects", HeightParams

        def reconstruct(self, inputs, params):
            return []

    fake_eps(FakeEntryPoint("oldie", contract_module("fake_old", reconstructors=[OldStyle()],
                                                     exporters=[Thing("glb")])),
             FakeEntryPoint("good", contract_module("fake_new", reconstructors=[HeightmapReconstructor()])))
    pm = PluginManager()
    assert list(pm.registry("reconstructors")) == ["heightmap"]
    err = pm.load_all()["oldie"].error
    assert err.startswith("reconstructors: 'old' does not meet the contract:")
    assert "no method run()" in err and "no method write()" in err
    assert list(pm.registry("exporters")) == ["glb"]  # the same plugin's conforming things still load
    assert pm.info["good"].error == ""
    with pytest.raises(RoadtwinError, match="unknown reconstructor 'old'"):
        pm.get("reconstructors", "old")


@pytest.mark.parametrize("kind,broken,words", [
    ("planners", "plan", ["plan takes (grid, start, goal)", "collision, params, rng"]),
    ("mergers", "Params", ["Params must be a dataclass"]),
    ("reconstructors", "produces", ["produces must be one of surface, defects, materials, got 'mesh'"]),
    ("exporters", "suffix", ["suffix must be a string starting with '.'"]),
    ("renderers", "prepare", ["no method prepare()", "RendererBase"]),
    ("renderers", "render", ["render takes (scene, cameras, params), the contract calls it as (scene, cameras, params, *, look=None)"]),
    ("defect_types", "description", ["no attribute 'description'"]),
])
def test_each_kind_checks_its_contract(kind, broken, words):
    thing = Thing("x", "d")
    if broken == "plan":
        thing.plan = lambda grid, start, goal: None
    elif broken == "render":  # the core passes look= under --randomize
        thing.render = lambda scene, cameras, params: iter(())
    elif broken == "Params":
        thing.Params = dict
    elif broken == "produces":
        thing.produces = "mesh"
    elif broken == "suffix":
        thing.suffix = "glb"
    else:  # hide a class attribute or method behind a subclass that lacks it
        cls = type("Broken", (), {k: v for k, v in vars(Thing).items() if k not in (broken, "__dict__")})
        thing = cls("x", "d")
        if broken == "description":
            del thing.description
    problems = "; ".join(contracts.check(kind, thing))
    for w in words:
        assert w in problems, problems
    assert contracts.check(kind, Thing("x", "d")) == []


def test_renderer_base_supplies_the_optional_capabilities():
    class Minimal(contracts.RendererBase):
        name, description, Params = "minimal", "render() only", NoParams

        def render(self, scene, cameras, params, *, look=None):
            yield from ()

    r = Minimal()
    assert contracts.check("renderers", r) == []
    scene = object()
    assert r.prepare(scene, None) is scene
    assert r.check_cameras(scene, [], None) is None
    assert r.render_events(scene, [], [], None, progress=None, threshold=0.2, seed=0) is None


def test_builtin_plugins_meet_their_contracts(monkeypatch):
    monkeypatch.delenv(ALLOW_ENV, raising=False)
    pm = PluginManager()
    for kind in KINDS:
        for name, thing in pm.registry(kind).items():
            assert contracts.check(kind, thing) == [], (kind, name)
    assert not any("contract" in i.error for i in pm.info.values())


# --------------------------------------------------------------------------- --param
from roadtwin_core.params import apply_params, parse_param_options  # noqa: E402

CURVED_XODR = __import__("pathlib").Path(__file__).parents[1] / "data" / "opendrive" / "curved_road_default.xodr"


def test_param_values_are_toml_scalars():
    got = parse_param_options(["a=0.5", "b = true", 'c="x y"', "d=rain", "e=[1, 2]", "f=-3", "g=1e-3"])
    assert got == {"a": 0.5, "b": True, "c": "x y", "d": "rain", "e": [1, 2], "f": -3, "g": 0.001}
    assert type(got["f"]) is int
    for bad, words in (("depth", "KEY=VALUE"), ("=1", "KEY=VALUE"), ("a b=1", "KEY=VALUE"), ("t={x=1}", "--param t")):
        with pytest.raises(RoadtwinError, match=words):
            parse_param_options([bad])
    with pytest.raises(RoadtwinError, match="a: given twice"):
        parse_param_options(["a=1", "a=2"])


def test_param_values_are_typed_and_bounded_like_a_layouts():
    p = apply_params(PotholeParams, {"depth_m": 0, "flat_bottom": True}, "pothole")
    assert p.depth_m == 0.0 and type(p.depth_m) is float and p.flat_bottom is True
    start = PotholeParams(radius_m=0.2)
    assert apply_params(start, {"sides": 5}, "pothole") == PotholeParams(radius_m=0.2, sides=5)
    assert start.sides == 12  # the instance given is not changed
    for values, words in (({"depth_m": "deep"}, "parameter depth_m must be float, got 'deep'"),
                          ({"sides": 2.5}, "parameter sides must be int"),
                          ({"sides": True}, "parameter sides must be int"),
                          ({"label": 3}, "parameter label must be str"),
                          ({"depth_m": 0.9}, "parameter depth_m must be <= 0.5, got 0.9"),
                          ({"depht_m": 1}, "unknown parameter(s) depht_m; known: depth_m, flat_bottom, label")):
        with pytest.raises(RoadtwinError) as exc:
            apply_params(PotholeParams, values, "pothole")
        assert str(exc.value).startswith("pothole: ") and words in str(exc.value), str(exc.value)


def test_import_param_reaches_the_importer(tmp_path, monkeypatch, capsys):
    """`--param` changes what the importer does: pieces of at most 5 m along a 44.35 m road."""
    import math

    monkeypatch.delenv(ALLOW_ENV, raising=False)
    out = tmp_path / "l.usda"
    code, stdout, err = run_cli(monkeypatch, capsys, PluginManager(), "import", "opendrive", str(CURVED_XODR),
                                "-o", str(out), "--param", "max_segment_length_m=5")
    assert code == 0, err
    assert f"{4 * math.ceil(44.347343 / 5.0)} segments" in stdout


@pytest.mark.parametrize("param,words", [
    ("nope=1", ["layout importer opendrive", "unknown parameter(s) nope", "max_segment_length_m"]),
    ("sample_step_m=100", ["parameter sample_step_m must be <= 10.0, got 100.0"]),
    ("sample_step_m=fine", ["parameter sample_step_m must be float, got 'fine'"]),
    ("sample_step_m", ["expected KEY=VALUE"]),
])
def test_bad_param_is_one_line_exit_2(tmp_path, monkeypatch, capsys, param, words):
    monkeypatch.delenv(ALLOW_ENV, raising=False)
    out = tmp_path / "l.usda"
    code, stdout, err = run_cli(monkeypatch, capsys, PluginManager(), "import", "opendrive", str(CURVED_XODR),
                                "-o", str(out), "--param", param)
    assert code == 2 and not out.exists()
    assert len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in " ".join(err.split()), err


def test_plugins_params_prints_fields_defaults_bounds_and_docs(monkeypatch, capsys):
    pm = PluginManager(load_entry_points=False)

    class Pothole(Thing):
        Params = PotholeParams

    pm.register(contract_module("fake_pp", defect_types=[Pothole("pothole", "a hole")],
                                exporters=[Thing("pothole", "same name, another kind")]), name="pp")
    monkeypatch.setenv("COLUMNS", "200")
    code, out, err = run_cli(monkeypatch, capsys, pm, "plugins", "--params", "pothole")
    assert code == 0, err
    rows = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[2:-1]]
            for line in out.splitlines() if line.startswith("│")}
    assert rows["depth_m"] == ["float", "0.05", "0.0 .. 0.5", "depth below the surface"]
    assert rows["radius_m"] == ["float", "0.3", ">= 0.01", ""]
    assert rows["flat_bottom"] == ["bool", "False", "", ""]
    assert "defect type pothole: a hole" in out and "exporter pothole: no parameters" in out
    code, out, err = run_cli(monkeypatch, capsys, pm, "plugins")
    assert code == 0 and "defect_types: pothole - a hole" in out
    code, out, err = run_cli(monkeypatch, capsys, pm, "plugins", "--params", "crater")
    assert code == 2 and "'crater'" in err and "known: pothole" in err


def test_compose_merger_param_reaches_a_copy_of_the_merger(tmp_path):
    """`compose --param` configures the merger used for this town only; the registered one keeps
    its defaults (plugins are shared objects)."""
    from pathlib import Path

    from roadtwin_cdt import CDTMerger

    from roadtwin_core.apps.compose.run import compose

    seen = []

    class SpyMerger(CDTMerger):
        name = "spy"

        def merge(self, segment, placements, surface, rules):
            seen.append(self.params)
            return super().merge(segment, placements, surface, rules)

    registered = SpyMerger()
    pm = PluginManager(load_entry_points=False)
    pm.register(contract_module("fake_spy", mergers=[registered]), name="spy_plugin")
    layout = Path(__file__).resolve().parents[2] / "stages" / "town.usda"
    compose(layout, tmp_path / "town", defects=0, seed=1, merger="spy", preview=False, executor="serial",
            pm=pm, merger_params={"min_angle_deg": 25})
    assert seen and {p.min_angle_deg for p in seen} == {25.0}
    assert registered.params.min_angle_deg == CDTMerger().params.min_angle_deg != 25.0
    # the stage and the summary say which values made the town (defaults included)
    from pxr import Usd
    import json as _json

    stage = Usd.Stage.Open(str(tmp_path / "town" / "town.usda"))
    recorded = _json.loads(stage.GetDefaultPrim().GetAttribute("roadtwin:compose:mergerParams").Get())
    assert recorded == {**dataclasses.asdict(CDTMerger().params), "min_angle_deg": 25.0}
    assert _json.loads((tmp_path / "town" / "summary.json").read_text())["merger_params"] == recorded
    with pytest.raises(RoadtwinError, match="merger spy: parameter min_angle_deg must be <= 30.0"):
        compose(layout, tmp_path / "town2", defects=0, merger="spy", preview=False, executor="serial", pm=pm,
                merger_params={"min_angle_deg": 31})
