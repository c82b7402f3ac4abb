#!/usr/bin/env python
"""Packs what the lent GPU machine lacks so that ``roadtwin render ... --device cuda`` (and
``bench/perception.py``) run there. Not a benchmark: a packing tool that lives beside them.

The GPU machine has Python 3.12 (x86_64, manylinux) with PyTorch, numpy, scipy, pillow,
matplotlib and OpenCV, but no usd-core, no warp and no package registry; one device call carries
at most 64 MiB, the repository's working tree included, and the machine stays warm 30 s between
calls. So this script

1. downloads (``pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation
   cp --platform manylinux...``) the wheels of the render path's distributions that the machine
   lacks: usd-core (the version installed here), warp-lang (1.19.0), shapely, triangle,
   manifold3d, typer and what they need (pydantic, rich, pluggy, ...), each pinned to the version
   installed here, so the GPU runs what the tests ran;
2. builds roadtwin's own wheel (``pip wheel --no-deps --no-build-isolation`` of a copy of the
   tree: the tree itself is not written to);
3. compresses every large wheel (re-stored uncompressed, then xz; warp's wheel without
   ``warp-clang.so``, warp's CPU compiler, and its example assets: there, use ``cuda`` devices)
   and cuts the lot into folders ``.gpu/pack1`` .. ``.gpu/packN`` (ignored through
   ``.git/info/exclude``), each no larger than the room the working tree leaves in one call;
4. writes ``unpack.sh`` into each folder: sourced on the device once every folder has been copied
   to ``/root/roadtwin-stage``, it reassembles and checks (sha256) the wheels, installs them once
   with ``pip install --no-index --no-deps --target /root/site`` and exports PYTHONPATH (and
   PATH, for the ``roadtwin`` command);
5. prints the calls to make, back to back: the carry list and the command of each.

Which distributions: the render path's imports (``roadtwin render`` with the warp renderer,
``--randomize``, a class map, every dataset format; measured with ``sys.modules`` after a render
here) map to RENDER_ROOTS; their requirements (read from the metadata installed here, markers
evaluated for CPython 3.12 on x86_64 Linux) are followed, stopping at DEVICE_HAS, the large
compiled distributions the GPU image already holds (numpy, scipy, pillow, matplotlib and its
needs, opencv-python-headless: ``--randomize`` blurs with cv2 and class maps dilate with it).
open3d is not packed: it is the CPU ray caster; ``--device cuda`` casts with warp. Small
pure-Python ones the image also holds (pluggy, rich, typer, ...) are packed anyway, pinned, so a
different version there cannot break the CLI.

Run here, in the project root (the download is ~180 MB, once: it keeps the wheels in
.gpu/wheels, and ``--skip-download .gpu/wheels`` re-packs from them, offline)::

    .venv/bin/python bench/gpu_pack.py                 # download, pack, print the calls
    .venv/bin/python bench/gpu_pack.py --skip-download .gpu/wheels --check
    .venv/bin/python bench/gpu_pack.py --extra-wheels .perception/wheels   # + the encoder's wheels

Measured (2026-11, usd-core 26.11, warp-lang 1.19.0, a 23.4 MiB tree): 19 wheels, 528 MiB as
installed wheels, 107 MiB carried in 3 calls (warp's xz stream, 84 MiB, spans all three); packing
took ~8 min on 2 cores (xz of ~450 MB). On an H100 the third call's unpack.sh reassembled and
installed them in 12 s (548 MB in /root/site); ``roadtwin compose stages/town.usda --defects 20``
and ``roadtwin render ... --device cuda --rig survey --views defects:0.6 --randomize --classmap
builtin:road_defects_br`` then ran there.

Options: ``--dest DIR`` (default .gpu), ``--python-version`` (3.12), ``--warp-version``
(1.19.0), ``--packages a,b`` (pack exactly these distributions instead of the render set),
``--extra-wheels DIR`` (add every wheel there), ``--part-mib`` (the most one folder holds;
default 64 MiB minus the working tree minus 2 MiB of slack minus ``--reserve-mib``, the room
kept in each call for other carried paths, e.g. a stage), ``--xz-min-mib`` (wheels from this
size on are xz-compressed; ``--xz-level``, default 6), ``--keep-warp-clang``, ``--check``
(reassemble and install the folders here, through unpack.sh, into a temporary target; where
this Python is the target version, ``import roadtwin_core`` is checked there with PYTHONPATH
only).

On the device, ``unpack.sh`` reads ROADTWIN_GPU_ROOT (default /root: the stage is
``$ROOT/roadtwin-stage``, the target ``$ROOT/site``), ROADTWIN_GPU_PYTHON (default python3) and
ROADTWIN_GPU_PIP_ARGS (more pip arguments). A call made from the repository root that runs
``python3 -m roadtwin_core.cli`` imports the tree's ``roadtwin_core`` (the current directory
comes first) and the wheel's plugins; the ``roadtwin`` command runs the wheel's code alone.
Re-pack after changing a plugin or the entry points, and when the working tree has grown since
packing (a call that would carry over 64 MiB is refused: the parts were cut to the room the tree
left then; ``--skip-download .gpu/wheels`` re-packs offline). Where there is no time for that,
the parts travel as well in smaller slices: ``tar -cf - -C .gpu pack1 pack2 pack3 | split -b 32M
-d - .gpu/chunks/c`` here, one call per slice carrying ``.gpu/chunks/cNN`` and copying it to
``/root/chunks``, then ``cat /root/chunks/c* | tar -xf - -C /root/untar`` and ``cp -f`` every
pack's files to ``/root/roadtwin-stage`` before sourcing ``unpack.sh`` (done so on 2026-11-26:
four calls for a 28 MiB tree).

A missing wheel (not on the index for that Python and platform, or not in the
``--skip-download`` folder) is one line naming it, exit 2.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.metadata
import json
import lzma
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

try:
    from packaging.markers import default_environment
    from packaging.requirements import Requirement
    from packaging.tags import compatible_tags, cpython_tags
    from packaging.utils import canonicalize_name, parse_wheel_filename
except ImportError:                      # pip vendors packaging
    from pip._vendor.packaging.markers import default_environment
    from pip._vendor.packaging.requirements import Requirement
    from pip._vendor.packaging.tags import compatible_tags, cpython_tags
    from pip._vendor.packaging.utils import canonicalize_name, parse_wheel_filename

REPO = Path(__file__).resolve().parents[1]
MIB = 1024 * 1024
CALL_LIMIT = 64 * MIB            # what one device call carries, the working tree included
SLACK = 2 * MIB                  # the tree grows a little between packing and calling
OVERHEAD = 64 * 1024             # unpack.sh + manifest.json in each folder
STAGE = "roadtwin-stage"
SITE = "site"

# The render path's distributions: what `roadtwin render --device cuda --randomize --classmap ...`
# imports (sys.modules after a render here), open3d left out (the CPU ray caster).
RENDER_ROOTS = ("usd-core", "warp-lang", "pluggy", "numpy", "scipy", "shapely", "triangle", "manifold3d",
                "typer", "rich", "pillow", "matplotlib", "opencv-python-headless")
# Large compiled distributions the GPU image holds (KINDS.md's list): followed no further.
DEVICE_HAS = ("numpy", "scipy", "pillow", "matplotlib", "opencv-python-headless", "contourpy", "cycler",
              "fonttools", "kiwisolver", "pyparsing", "python-dateutil", "six", "packaging")
# Files of a wheel not carried (prefixes inside the wheel), by distribution.
WARP_DROP = ("warp/bin/warp-clang.so", "warp/examples/assets/")


class PackError(Exception):
    """One line for the user; exit 2."""


# ------------------------------------------------------------------------------- target
def platforms() -> list[str]:
    return [*(f"manylinux_2_{n}_x86_64" for n in range(39, 16, -1)), "manylinux2014_x86_64",
            "manylinux2010_x86_64", "manylinux1_x86_64"]


def target_tags(python_version: str) -> set:
    major, minor = (int(x) for x in python_version.split(".")[:2])
    abi = f"cp{major}{minor}"
    plats = platforms()
    return {*cpython_tags((major, minor), abis=[abi, "abi3", "none"], platforms=plats),
            *compatible_tags((major, minor), abi, platforms=plats)}


def marker_env(python_version: str) -> dict:
    env = dict(default_environment())
    env.update(python_version=".".join(python_version.split(".")[:2]), python_full_version=f"{python_version}.0"
               if python_version.count(".") == 1 else python_version, sys_platform="linux", platform_system="Linux",
               platform_machine="x86_64", os_name="posix", implementation_name="cpython",
               platform_python_implementation="CPython", extra="")
    return env


def installed_version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def render_set(python_version: str, warp_version: str) -> dict[str, str | None]:
    """RENDER_ROOTS and their requirements (as installed here), less DEVICE_HAS: name -> pin."""
    env = marker_env(python_version)
    stop = {canonicalize_name(n) for n in DEVICE_HAS}
    found: dict[str, str | None] = {}
    todo = [canonicalize_name(n) for n in RENDER_ROOTS]
    while todo:
        name = todo.pop(0)
        if name in found or name in stop:
            continue
        found[name] = warp_version if name == "warp-lang" else installed_version(name)
        try:
            requires = importlib.metadata.requires(name) or []
        except importlib.metadata.PackageNotFoundError:
            continue
        for line in requires:
            req = Requirement(line)
            if req.marker is None or req.marker.evaluate(env):
                todo.append(canonicalize_name(req.name))
    return found


# ------------------------------------------------------------------------------- wheels
def download(pins: dict[str, str | None], dest: Path, python_version: str) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    major, minor = python_version.split(".")[:2]
    specs = [f"{n}=={v}" if v else n for n, v in pins.items()]
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
           "--python-version", python_version, "--implementation", "cp",
           "--abi", f"cp{major}{minor}", "--abi", "abi3", "--abi", "none",
           *(a for p in platforms() for a in ("--platform", p)), "-d", str(dest), *specs]
    print(f"gpu_pack: downloading {len(specs)} wheels for CPython {python_version} manylinux x86_64 into {dest}",
          flush=True)
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode:
        missing = re.findall(r"No matching distribution found for (\S+)", run.stderr)
        if missing:
            raise PackError(f"no wheel for {', '.join(missing)} for CPython {python_version} manylinux x86_64 "
                            f"on the package index")
        last = [ln for ln in run.stderr.splitlines() if ln.strip()][-1:] or ["(no output)"]
        raise PackError(f"pip download failed: {last[0].strip()}")


def pick_wheels(pins: dict[str, str | None], folder: Path, python_version: str) -> dict[str, Path]:
    """name -> the wheel in ``folder`` for it (the pinned version where pinned), for the target."""
    tags = target_tags(python_version)
    have: dict[str, list[tuple]] = {}
    for whl in sorted(folder.glob("*.whl")) if folder.is_dir() else []:
        try:
            name, version, _, wtags = parse_wheel_filename(whl.name)
        except Exception:
            continue
        if wtags & tags:
            have.setdefault(canonicalize_name(name), []).append((version, whl))
    chosen, missing = {}, []
    for name, pin in pins.items():
        options = have.get(canonicalize_name(name), [])
        match = [w for v, w in options if pin is None or str(v) == pin]
        if match:
            chosen[name] = match[0]
        elif options:          # another version only: take the newest, and say so
            version, whl = max(options, key=lambda o: o[0])
            print(f"gpu_pack: note: {name} {version} packed ({pin} is installed here)")
            chosen[name] = whl
        else:
            missing.append(f"{name}=={pin}" if pin else name)
    if missing:
        raise PackError(f"no wheel for {', '.join(missing)} (CPython {python_version}, manylinux x86_64) in {folder}")
    return chosen


def build_project_wheel(out: Path) -> Path:
    """roadtwin's wheel, built from a copy of the tree (the tree is not written to)."""
    with tempfile.TemporaryDirectory(prefix="gpu_pack_src_") as tmp:
        src = Path(tmp) / "src"
        src.mkdir()
        ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
        for name in ("pyproject.toml", "README.md", "setup.py", "setup.cfg", "MANIFEST.in", "LICENSE"):
            if (REPO / name).is_file():
                shutil.copy2(REPO / name, src / name)
        for name in ("roadtwin_core", "plugins"):
            shutil.copytree(REPO / name, src / name, ignore=ignore)
        out.mkdir(parents=True, exist_ok=True)
        run = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                              "-w", str(out), str(src)], capture_output=True, text=True)
        if run.returncode:
            last = [ln for ln in run.stderr.splitlines() if ln.strip()][-1:] or ["(no output)"]
            raise PackError(f"building roadtwin's wheel failed: {last[0].strip()}")
    wheels = sorted(out.glob("roadtwin-*.whl"))
    if not wheels:
        raise PackError("building roadtwin's wheel wrote no roadtwin-*.whl")
    return wheels[-1]


def restore(src: Path, dst: Path, drop: tuple[str, ...] = ()) -> int:
    """The wheel ``src`` as an uncompressed zip at ``dst`` (xz compresses that far better than
    deflated members), without the members under ``drop`` (their RECORD lines go too: the others'
    hashes are of their content, so they stay right). Returns the bytes dropped."""
    dropped = 0
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_STORED) as zout:
        gone = set()
        for info in zin.infolist():
            if drop and info.filename.startswith(drop):
                gone.add(info.filename)
                dropped += info.file_size
        for info in zin.infolist():
            if info.filename in gone:
                continue
            data = zin.read(info)
            if gone and info.filename.endswith(".dist-info/RECORD"):
                lines = data.decode().splitlines(keepends=True)
                data = "".join(ln for ln in lines if ln.split(",", 1)[0] not in gone).encode()
            out = zipfile.ZipInfo(info.filename, info.date_time)
            out.external_attr = info.external_attr
            out.compress_type = zipfile.ZIP_STORED
            zout.writestr(out, data)
    return dropped


def xz(src: Path, dst: Path, level: int = 6) -> None:
    if shutil.which("xz"):
        with open(dst, "wb") as f:
            subprocess.run(["xz", f"-{level}", "-T0", "-c", str(src)], stdout=f, check=True)
    else:
        with open(src, "rb") as fin, lzma.open(dst, "wb", preset=level) as fout:
            shutil.copyfileobj(fin, fout, 4 * MIB)


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(4 * MIB), b""):
            h.update(block)
    return h.hexdigest()


# ------------------------------------------------------------------------------- packing
@dataclass
class Item:
    wheel: str                      # the wheel's file name on the device
    path: Path                      # what travels (the wheel, or its .xz)
    xz: bool
    sha256: str                     # of the wheel as installed
    pieces: list = field(default_factory=list)   # [pack number, file name]


def tree_bytes() -> int:
    """What travels with every call: tracked and untracked-not-ignored files."""
    try:
        out = subprocess.run(["git", "ls-files", "-z", "-co", "--exclude-standard"], cwd=REPO, capture_output=True,
                             check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        raise PackError(f"{REPO} is not a git checkout: give --part-mib") from None
    total = 0
    for name in out.decode(errors="surrogateescape").split("\0"):
        if name:
            try:
                total += (REPO / name).lstat().st_size
            except OSError:
                pass
    return total


def ignore_in_git(dest: Path) -> None:
    """``/.gpu/`` (dest's top folder inside the repo) into .git/info/exclude, as gpu-warp-pack does."""
    try:
        rel = dest.resolve().relative_to(REPO)
    except ValueError:
        return
    top = f"/{rel.parts[0]}/" if rel.parts else None
    git_dir = REPO / ".git"
    if top is None or not git_dir.is_dir():
        return
    exclude = git_dir / "info" / "exclude"
    exclude.parent.mkdir(parents=True, exist_ok=True)
    lines = exclude.read_text().splitlines() if exclude.exists() else []
    if top not in lines:
        with open(exclude, "a") as f:
            f.write(("" if not lines or exclude.read_text().endswith("\n") else "\n") + top + "\n")


def split(items: list[Item], dest: Path, room: int) -> int:
    """Items into dest/pack1.., each folder's payload at most ``room`` bytes; returns the count."""
    for old in dest.glob("pack[0-9]*"):
        shutil.rmtree(old)
    pack, used = 1, 0
    (dest / "pack1").mkdir(parents=True)
    for item in items:
        size, offset, k = item.path.stat().st_size, 0, 0
        with open(item.path, "rb") as f:
            while True:
                if used >= room and size > offset:
                    pack, used = pack + 1, 0
                    (dest / f"pack{pack}").mkdir()
                n = min(room - used, size - offset)
                name = item.path.name if (offset == 0 and n == size) else f"{item.path.name}.{k:03d}"
                with open(dest / f"pack{pack}" / name, "wb") as out:
                    left = n
                    while left:
                        block = f.read(min(left, 4 * MIB))
                        out.write(block)
                        left -= len(block)
                item.pieces.append([pack, name])
                offset, used, k = offset + n, used + n, k + 1
                if offset >= size:
                    break
    return pack


UNPACK = r'''# Sourced on the GPU machine (bash), once every folder of this pack was copied to the stage:
#   . /root/roadtwin-stage/unpack.sh && python3 ...
# Reassembles and checks the wheels that bench/gpu_pack.py packed, installs them once with
# pip install --no-index --no-deps --target, and exports PYTHONPATH and PATH.
# ROADTWIN_GPU_ROOT (default /root): the stage is $ROOT/roadtwin-stage, the target $ROOT/site.
# ROADTWIN_GPU_PYTHON (default python3); ROADTWIN_GPU_PIP_ARGS: more pip install arguments.
_gp_root=${ROADTWIN_GPU_ROOT:-/root}
_gp_site=$_gp_root/site
if "${ROADTWIN_GPU_PYTHON:-python3}" - "$_gp_root/roadtwin-stage" "$_gp_site" <<'PY'
import hashlib, json, lzma, os, shlex, shutil, subprocess, sys
stage, site = sys.argv[1], sys.argv[2]
m = json.load(open(os.path.join(stage, "manifest.json")))
marker = os.path.join(site, ".roadtwin-gpu-pack-" + m["id"])
if os.path.exists(marker):
    sys.exit(0)
absent = sorted({p for it in m["items"] for p, name in it["pieces"] if not os.path.exists(os.path.join(stage, name))})
if absent:
    print("gpu pack: the stage %s lacks the files of call(s) %s of %d: make those calls (each copies its "
          "folder there) before this one" % (stage, ", ".join(map(str, absent)), m["packs"]), file=sys.stderr)
    sys.exit(1)
wheels = os.path.join(stage, "wheels")
shutil.rmtree(wheels, ignore_errors=True)
os.makedirs(wheels)
for it in m["items"]:
    target = os.path.join(wheels, it["wheel"])
    with open(target, "wb") as out:
        for _, name in it["pieces"]:
            with open(os.path.join(stage, name), "rb") as f:
                shutil.copyfileobj(f, out, 1 << 22)
    if it["xz"]:
        packed = target + ".xz"
        os.replace(target, packed)
        with lzma.open(packed) as f, open(target, "wb") as out:
            shutil.copyfileobj(f, out, 1 << 22)
        os.remove(packed)
    h = hashlib.sha256()
    with open(target, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)
    if h.hexdigest() != it["sha256"]:
        print("gpu pack: %s does not match its checksum: a file of another pack is in %s; make the "
              "calls of this pack again" % (it["wheel"], stage), file=sys.stderr)
        sys.exit(1)
shutil.rmtree(site, ignore_errors=True)
cmd = [sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--no-compile",
       "--no-cache-dir", "--disable-pip-version-check", "--target", site,
       *shlex.split(os.environ.get("ROADTWIN_GPU_PIP_ARGS", "")),
       *(os.path.join(wheels, it["wheel"]) for it in m["items"])]
if subprocess.run(cmd).returncode:
    print("gpu pack: pip install into %s failed (above)" % site, file=sys.stderr)
    sys.exit(1)
shutil.rmtree(wheels, ignore_errors=True)
open(marker, "w").write("\n".join(it["wheel"] for it in m["items"]) + "\n")
print("gpu pack: installed %d wheels into %s" % (len(m["items"]), site), file=sys.stderr)
PY
then
  case ":${PYTHONPATH:-}:" in *":$_gp_site:"*) ;; *) export PYTHONPATH=$_gp_site${PYTHONPATH:+:$PYTHONPATH} ;; esac
  case ":$PATH:" in *":$_gp_site/bin:"*) ;; *) export PATH=$_gp_site/bin:$PATH ;; esac
else
  false
fi
'''


def write_pack(dest: Path, items: list[Item], packs: int, python_version: str) -> str:
    ident = hashlib.sha256("".join(i.sha256 for i in items).encode()).hexdigest()[:16]
    manifest = {"id": ident, "python": python_version, "packs": packs,
                "items": [{"wheel": i.wheel, "xz": i.xz, "sha256": i.sha256, "pieces": i.pieces} for i in items]}
    for k in range(1, packs + 1):
        (dest / f"pack{k}" / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
        (dest / f"pack{k}" / "unpack.sh").write_text(UNPACK)
    return ident


def folder_bytes(folder: Path) -> int:
    return sum(f.stat().st_size for f in folder.iterdir() if f.is_file())


def rel(path: Path) -> str:
    try:
        return path.resolve().relative_to(REPO).as_posix()
    except ValueError:
        return str(path)


def calls(dest: Path, packs: int) -> list[tuple[str, str]]:
    """(carry, command) of each call."""
    out = []
    stage = f"/root/{STAGE}"
    for k in range(1, packs + 1):
        folder = rel(dest / f"pack{k}")
        cmd = f"mkdir -p {stage} && cp {folder}/* {stage}/"
        if k == packs:
            cmd += f" && . {stage}/unpack.sh && YOUR_COMMAND"
        out.append((folder, cmd))
    return out


# ------------------------------------------------------------------------------- check
def check(dest: Path, packs: int, python_version: str) -> str:
    """Make the calls here: copy each folder into a temporary stage, source unpack.sh (its python
    this interpreter), install into a clean target; import roadtwin_core there with PYTHONPATH
    only where this Python is the target version."""
    same = f"{sys.version_info.major}.{sys.version_info.minor}" == ".".join(python_version.split(".")[:2])
    with tempfile.TemporaryDirectory(prefix="gpu_pack_check_") as tmp:
        root = Path(tmp)
        stage = root / STAGE
        stage.mkdir()
        for k in range(1, packs + 1):
            for f in (dest / f"pack{k}").iterdir():
                shutil.copy2(f, stage / f.name)
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
        env.update(ROADTWIN_GPU_ROOT=str(root), ROADTWIN_GPU_PYTHON=sys.executable)
        if not same:
            major, minor = python_version.split(".")[:2]
            env["ROADTWIN_GPU_PIP_ARGS"] = " ".join(
                ["--only-binary=:all:", "--python-version", python_version, "--implementation", "cp",
                 "--abi", f"cp{major}{minor}", "--abi", "abi3", "--abi", "none",
                 *(a for p in platforms() for a in ("--platform", p))])
        probe = ("import importlib.metadata as m, os, sys; site = os.environ['ROADTWIN_GPU_ROOT'] + '/site'; "
                 "import roadtwin_core; assert roadtwin_core.__file__.startswith(site), roadtwin_core.__file__; "
                 "d = m.distribution('roadtwin'); "
                 "print('roadtwin', d.version, 'from', os.path.dirname(roadtwin_core.__file__), '; plugins:', "
                 "len(d.entry_points.select(group='roadtwin')))")
        script = '. "$ROADTWIN_GPU_ROOT/roadtwin-stage/unpack.sh" || exit 1\n'
        script += f'"$ROADTWIN_GPU_PYTHON" -c "{probe}"\n' if same else 'ls "$ROADTWIN_GPU_ROOT/site"\n'
        run = subprocess.run(["bash", "-c", script], cwd=tmp, env=env, capture_output=True, text=True)
        if run.returncode:
            last = [ln for ln in (run.stderr + run.stdout).splitlines() if ln.strip()][-1:] or ["(no output)"]
            raise PackError(f"check failed: {last[0].strip()}")
        if same:
            return run.stdout.strip()
        dists = [n for n in run.stdout.split() if n.endswith(".dist-info")]
        return (f"{len(dists)} distributions installed into a clean target (Python {python_version} wheels; "
                f"this Python is {sys.version_info.major}.{sys.version_info.minor}, so the import was not tried)")


# ------------------------------------------------------------------------------- main
def pack(args) -> int:
    dest = Path(args.dest).resolve()
    pv = args.python_version
    if args.packages is not None:
        names = [canonicalize_name(n) for n in args.packages.split(",") if n.strip()]
        pins = {n: args.warp_version if n == "warp-lang" else installed_version(n) for n in names}
    else:
        pins = render_set(pv, args.warp_version)
    pins.pop("roadtwin", None)
    if args.part_mib is not None:
        room = int(args.part_mib * MIB) - OVERHEAD
        tree = None
    else:
        tree = tree_bytes()
        room = CALL_LIMIT - SLACK - tree - int(args.reserve_mib * MIB) - OVERHEAD
    if tree is None and room < 4096:
        raise PackError(f"--part-mib {args.part_mib} leaves no room beside unpack.sh and the manifest")
    if tree is not None and room < 4 * MIB:
        raise PackError(f"each call leaves {max(room, 0) / MIB:.1f} MiB for the pack (tree {tree / MIB:.1f} MiB, "
                        f"--reserve-mib {args.reserve_mib:g}): make the tree or the reserve smaller")

    dest.mkdir(parents=True, exist_ok=True)
    ignore_in_git(dest)
    if args.skip_download:
        wheel_dir = Path(args.skip_download)
    else:
        wheel_dir = dest / "wheels"
        download(pins, wheel_dir, pv)
    chosen = pick_wheels(pins, wheel_dir, pv)
    extra = sorted(Path(args.extra_wheels).glob("*.whl")) if args.extra_wheels else []
    if args.extra_wheels and not extra:
        raise PackError(f"--extra-wheels {args.extra_wheels}: no wheels there")

    work = dest / "work"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    try:
        wheels = [build_project_wheel(work / "project"), *chosen.values(), *extra]
        items, installed = [], 0
        for whl in wheels:
            name = canonicalize_name(parse_wheel_filename(whl.name)[0])
            drop = WARP_DROP if name == "warp-lang" and not args.keep_warp_clang else ()
            if whl.stat().st_size >= args.xz_min_mib * MIB or drop:
                stored = work / whl.name
                restore(whl, stored, drop)
                xz(stored, work / f"{whl.name}.xz", args.xz_level)
                items.append(Item(whl.name, work / f"{whl.name}.xz", True, sha256(stored)))
                installed += stored.stat().st_size
                stored.unlink()
            else:
                items.append(Item(whl.name, whl, False, sha256(whl)))
                installed += whl.stat().st_size
        items.sort(key=lambda i: (i.path.stat().st_size, i.wheel))    # small first, the big ones split last
        packs = split(items, dest, room)
        ident = write_pack(dest, items, packs, pv)
    finally:
        shutil.rmtree(work, ignore_errors=True)

    carried = sum(folder_bytes(dest / f"pack{k}") for k in range(1, packs + 1))
    largest = max(folder_bytes(dest / f"pack{k}") for k in range(1, packs + 1))
    listing = ", ".join(f"{canonicalize_name(parse_wheel_filename(i.wheel)[0])} {parse_wheel_filename(i.wheel)[1]}"
                        for i in sorted(items, key=lambda i: i.wheel))
    print(f"gpu_pack: pack {ident}: {len(items)} wheels ({listing})")
    print(f"gpu_pack: {installed / MIB:.1f} MiB of wheels, {carried / MIB:.1f} MiB carried in {packs} folder(s) of "
          f"at most {(room + OVERHEAD) / MIB:.1f} MiB (largest {largest / MIB:.1f} MiB)"
          + (f"; the working tree ({tree / MIB:.1f} MiB) travels with each call" if tree is not None else ""))
    if args.check:
        print(f"gpu_pack: check: {check(dest, packs, pv)}")
    print(f"Make these {packs} device call(s) back to back (a machine is given back 30 s after a call ends):")
    for k, (carry, cmd) in enumerate(calls(dest, packs), 1):
        print(f"  call {k}: carry [\"{carry}\"]  command: {cmd}")
    print(f"Later calls on the same warm machine: . /root/{STAGE}/unpack.sh && YOUR_COMMAND")
    print("YOUR_COMMAND e.g.: roadtwin render STAGE.usda -o $OUT/render --device cuda --rig survey "
          "--views defects:0.6 --randomize --classmap builtin:road_defects_br --executor serial")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Pack usd-core, warp, roadtwin and the render path's other wheels for "
                                             "the GPU machine, in folders that fit one device call each.")
    ap.add_argument("--dest", default=str(REPO / ".gpu"), help="where pack1..N go (default: .gpu)")
    ap.add_argument("--python-version", default="3.12", help="the GPU machine's Python (default 3.12)")
    ap.add_argument("--warp-version", default="1.19.0")
    ap.add_argument("--skip-download", metavar="DIR", help="take the wheels from DIR instead of the index")
    ap.add_argument("--packages", help="comma-separated distributions to pack instead of the render set")
    ap.add_argument("--extra-wheels", metavar="DIR", help="also pack every wheel in DIR")
    ap.add_argument("--part-mib", type=float, help="the most one folder holds (default: what the tree leaves)")
    ap.add_argument("--reserve-mib", type=float, default=0.0, help="room kept in each call for other carried paths")
    ap.add_argument("--xz-min-mib", type=float, default=2.0, help="xz-compress wheels from this size on")
    ap.add_argument("--xz-level", type=int, default=6, choices=range(10), metavar="0-9", help="xz preset (default 6)")
    ap.add_argument("--keep-warp-clang", action="store_true", help="keep warp's CPU compiler (~69 MB more)")
    ap.add_argument("--check", action="store_true", help="reassemble and install the pack here, in a temporary target")
    args = ap.parse_args(argv)
    try:
        return pack(args)
    except PackError as exc:
        print(f"gpu_pack: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
