"""bench/gpu_pack.py: packs wheels for the GPU machine into folders that fit one device call each.

Offline: the pack is made from a local wheel set (roadtwin's own wheel, built by the script from
a copy of the tree, and a fake wheel made here), never from the package index. The folders are
then "carried" the way the device calls do it (each copied into one stage folder), unpack.sh is
sourced with bash with its /root paths pointed at a temporary folder, and the wheels it installs
into a clean ``pip install --target`` folder import with PYTHONPATH alone.
"""
from __future__ import annotations

import importlib.util
import json
import os
import random
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from bench_script import load_bench_script

ROOT = Path(__file__).resolve().parents[2]
MIB = 1024 * 1024
PART_MIB = 0.3
HERE_PY = f"{sys.version_info.major}.{sys.version_info.minor}"

pytestmark = pytest.mark.skipif(importlib.util.find_spec("setuptools") is None,
                                reason="building roadtwin's wheel needs setuptools (--no-build-isolation)")


def _tool():
    return load_bench_script("gpu_pack")


def fake_wheel(folder: Path, name: str = "fake_tiny", version: str = "1.0", payload: int = 1000) -> Path:
    """A pure-Python wheel whose module carries ``payload`` bytes of hex noise (compressible by
    about half; fake_big's is big enough to be xz-compressed and cut across folders)."""
    data = random.Random(0).randbytes(payload // 2).hex()
    dist = f"{name}-{version}.dist-info"
    files = {
        f"{name}/__init__.py": f"VALUE = 42\nNOISE = {data!r}\n",
        f"{dist}/METADATA": f"Metadata-Version: 2.1\nName: {name.replace('_', '-')}\nVersion: {version}\n",
        f"{dist}/WHEEL": "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
    }
    files[f"{dist}/RECORD"] = "".join(f"{p},,\n" for p in files) + f"{dist}/RECORD,,\n"
    path = folder / f"{name}-{version}-py3-none-any.whl"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for p, text in files.items():
            z.writestr(p, text)
    return path


@pytest.fixture(scope="module")
def packed(tmp_path_factory):
    tool = _tool()
    tmp = tmp_path_factory.mktemp("gpu_pack")
    wheels = tmp / "wheels"
    wheels.mkdir()
    fake_wheel(wheels)
    fake_wheel(wheels, "fake_big", payload=2_400_000)
    dest = tmp / "dest"
    rc = tool.main(["--dest", str(dest), "--skip-download", str(wheels), "--packages", "fake-tiny,fake-big",
                    "--part-mib", str(PART_MIB), "--xz-min-mib", "0.9", "--xz-level", "0", "--python-version", HERE_PY,
                    "--check"])
    assert rc == 0
    return tool, dest


def stage_and_source(dest: Path, root: Path, packs: list[int], probe: str) -> subprocess.CompletedProcess:
    """Copy the given folders into root/roadtwin-stage (as the calls do), source unpack.sh there
    (bash, /root pointed at ``root``) and run ``probe`` with this Python: PYTHONPATH as set by
    unpack.sh only."""
    stage = root / "roadtwin-stage"
    stage.mkdir(parents=True, exist_ok=True)
    for k in packs:
        for f in (dest / f"pack{k}").iterdir():
            shutil.copy2(f, stage / f.name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "ROADTWIN_GPU_PIP_ARGS")}
    env.update(ROADTWIN_GPU_ROOT=str(root), ROADTWIN_GPU_PYTHON=sys.executable)
    script = f'. "$ROADTWIN_GPU_ROOT/roadtwin-stage/unpack.sh" && echo "PYTHONPATH=$PYTHONPATH" && ' \
             f'"$ROADTWIN_GPU_PYTHON" -c "{probe}"'
    return subprocess.run(["bash", "-c", script], cwd=root, env=env, capture_output=True, text=True, timeout=300)


def test_parts_respect_the_size_budget_and_cut_the_big_wheel(packed):
    _, dest = packed
    folders = sorted(dest.glob("pack[0-9]*"), key=lambda p: int(p.name[4:]))
    assert len(folders) >= 3
    for f in folders:
        size = sum(x.stat().st_size for x in f.iterdir())
        assert size <= PART_MIB * MIB, f"{f.name}: {size} bytes"
        assert {"unpack.sh", "manifest.json"} <= {x.name for x in f.iterdir()}
    manifest = json.loads((folders[0] / "manifest.json").read_text())
    items = {i["wheel"]: i for i in manifest["items"]}
    assert set(items) == {"fake_tiny-1.0-py3-none-any.whl", "fake_big-1.0-py3-none-any.whl",
                          next(w for w in items if w.startswith("roadtwin-"))}
    big, tiny = items["fake_big-1.0-py3-none-any.whl"], items["fake_tiny-1.0-py3-none-any.whl"]
    assert big["xz"] and len(big["pieces"]) >= 2       # compressed, and cut across folders
    assert not tiny["xz"] and len(tiny["pieces"]) == 1
    assert manifest["packs"] == len(folders)


def test_unpack_installs_into_a_clean_target_and_imports_with_pythonpath_only(packed, tmp_path):
    _, dest = packed
    packs = list(range(1, len(list(dest.glob("pack[0-9]*"))) + 1))
    probe = ("import importlib.metadata as m, fake_tiny, fake_big, roadtwin_core, roadtwin_core.cli; "
             "print(fake_tiny.VALUE + len(fake_big.NOISE), roadtwin_core.__file__, fake_big.__file__, "
             "m.distribution('roadtwin').locate_file(''), "
             "sorted(e.name for e in m.distribution('roadtwin').entry_points.select(group='roadtwin'))[:2])")
    run = stage_and_source(dest, tmp_path, packs, probe)
    assert run.returncode == 0, run.stderr
    site = str(tmp_path / "site")
    assert f"PYTHONPATH={site}\n" in run.stdout
    out = run.stdout.splitlines()[-1].split(" ", 4)
    assert out[0] == str(42 + 2_400_000)
    assert all(p.startswith(site) for p in out[1:4]), out      # from the target, not the checkout
    assert "boolean" in out[4] and "cdt" in out[4]             # the plugins' entry points came along
    assert "installed 3 wheels" in run.stderr
    assert (tmp_path / "site" / "fake_tiny" / "__init__.py").is_file()
    assert not (tmp_path / "roadtwin-stage" / "wheels").exists()

    again = stage_and_source(dest, tmp_path, [], "import fake_tiny")    # installed once: sourcing again is instant
    assert again.returncode == 0 and "installed" not in again.stderr


def test_a_missing_call_is_named(packed, tmp_path):
    _, dest = packed
    n = len(list(dest.glob("pack[0-9]*")))
    run = stage_and_source(dest, tmp_path, [k for k in range(1, n + 1) if k != 2], "print(1)")
    assert run.returncode != 0
    lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "call(s) 2 of" in lines[0], run.stderr
    assert not (tmp_path / "site").exists()


def test_a_missing_wheel_is_one_clear_line(tmp_path, capsys):
    tool = _tool()
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    fake_wheel(wheels)
    rc = tool.main(["--dest", str(tmp_path / "dest"), "--skip-download", str(wheels),
                    "--packages", "fake-tiny,shapely", "--part-mib", "8"])
    assert rc == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1
    assert err[0].startswith("gpu_pack: no wheel for shapely") and str(wheels) in err[0]
    assert "CPython 3.12" in err[0]
    assert not (tmp_path / "dest" / "pack1").exists()


def test_the_render_set_is_what_the_gpu_machine_lacks():
    tool = _tool()
    pins = tool.render_set("3.12", "1.19.0")
    assert {"usd-core", "warp-lang", "shapely", "triangle", "manifold3d", "typer", "pluggy"} <= set(pins)
    assert pins["warp-lang"] == "1.19.0"
    assert not {"numpy", "scipy", "pillow", "matplotlib", "opencv-python-headless", "open3d", "torch"} & set(pins)
