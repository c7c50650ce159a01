#!/usr/bin/env bash
# Install system libraries that optional pbdyn dependencies need, only when they are missing.
# open3d (extra "mesh") loads libusb-1.0 at import time.
set -u
if ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so'; then
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "pbdyn: libusb-1.0 is missing; install it with your package manager (needed by open3d)" >&2
  exit 0
fi
SUDO=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
echo "pbdyn: installing libusb-1.0-0 (needed by open3d)" >&2
$SUDO apt-get update -qq >/dev/null 2>&1 || true
$SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 || echo "pbdyn: could not install libusb-1.0-0; open3d may fail to import" >&2
