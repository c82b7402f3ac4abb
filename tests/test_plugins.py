"""The plugin manager and typed parameters.

Entry points are faked by replacing ``importlib.metadata.entry_points`` (the function
``roadtwin_core.plugins`` calls) so these tests do not depend on which built-in plugins exist yet.
"""
from __future__ import annotations

import dataclasses
import importlib.metadata
import math
import types

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

    def __init__(self, name: str, description: str = "") -> None:
        self.name = name
        self.description = description

    def sample_params(self, rng): return NoParams()
    def generate(self, params, rng, name): return None
    def run(self, inputs, params): return None
    def write(self, result, out): return out
    def merge(self, segment, placements, surface, rules): return None
    def load(self, *args): return None  # layout importers (path, params), surface sources (arg, bounds, seed)
    def render(self, scene, cameras, params): return iter(())
    def prepare(self, scene, params): return scene
    def check_cameras(self, prepared, cameras, params): return None
    def render_events(self, scene, cameras, times, params, progress=None, threshold=0.2, seed=0): return None
    def simulate(self, road_mesh, vehicles, params): return None
    def plan(self, grid, start, goal, vehicle, collision, params, rng): return None
    def export(self, stage_path, out_path): return out_path


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
