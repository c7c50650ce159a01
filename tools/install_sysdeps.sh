#!/usr/bin/env bash
# Install the system packages pbdyn's optional parts and tests need, only when they are missing:
#   libusb-1.0    open3d (extra "mesh") loads it at import time;
#   chromium, chromium-driver   the HTML report's browser test (tests/test_html_report.py);
#   xvfb          a virtual display for the PyBullet GUI test (tests/test_gui.py);
#   g++           builds the native ruckig batch (pbdyn/planning/native; optional: planners are faster with it).
set -u
need=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so' || need+=(libusb-1.0-0)
command -v chromium >/dev/null 2>&1 || [ -x /usr/bin/chromium ] || need+=(chromium)
command -v chromedriver >/dev/null 2>&1 || [ -x /usr/bin/chromedriver ] || need+=(chromium-driver)
command -v xvfb-run >/dev/null 2>&1 || need+=(xvfb)
command -v c++ >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 || need+=(g++)
[ ${#need[@]} -eq 0 ] && exit 0
if ! command -v apt-get >/dev/null 2>&1; then
  echo "pbdyn: missing system packages (${need[*]}); install them with your package manager (open3d needs libusb-1.0," \
       "the HTML report test a headless Chromium and its driver, the GUI test xvfb, the native ruckig batch g++)" >&2
  exit 0
fi
SUDO=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
echo "pbdyn: installing ${need[*]}" >&2
$SUDO apt-get update -qq >/dev/null 2>&1 || true
$SUDO apt-get install -y -qq "${need[@]}" >/dev/null 2>&1 || echo "pbdyn: could not install ${need[*]}" >&2
