#!/usr/bin/env bash
# Install the system packages pbdyn needs, only when they are missing.
#
#   tools/install_sysdeps.sh           what pbdyn itself uses (`make demo`):
#     libusb-1.0    open3d (extra "mesh") loads it at import time;
#     g++           builds the native ruckig batch (pbdyn/planning/primitives/native; optional: planners are
#                   faster with it).
#   tools/install_sysdeps.sh --test    those, and what only the tests use (`make test`):
#     chromium, chromium-driver   the HTML report's browser test (tests/test_html_report.py);
#     xvfb          a virtual display for the PyBullet GUI test (tests/test_gui.py).
#   --dry-run (with either): print the missing packages, one line, and install nothing.
#
# Without apt-get, or when the install fails, it names what is missing in one line on stderr and exits 0: every
# package here is optional (the tests that need one skip without it).
set -u
test_deps=0
dry_run=0
for arg in "$@"; do
  case "$arg" in
    --test) test_deps=1 ;;
    --dry-run) dry_run=1 ;;
    *) echo "usage: tools/install_sysdeps.sh [--test] [--dry-run]" >&2; exit 2 ;;
  esac
done

need=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so' || need+=(libusb-1.0-0)
command -v c++ >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 || need+=(g++)
why="open3d needs libusb-1.0, the native ruckig batch g++"
if [ "$test_deps" -eq 1 ]; then
  command -v chromium >/dev/null 2>&1 || [ -x /usr/bin/chromium ] || need+=(chromium)
  command -v chromedriver >/dev/null 2>&1 || [ -x /usr/bin/chromedriver ] || need+=(chromium-driver)
  command -v xvfb-run >/dev/null 2>&1 || need+=(xvfb)
  why="$why, the HTML report test a headless Chromium and its driver, the GUI test xvfb"
fi

if [ "$dry_run" -eq 1 ]; then
  echo "missing: ${need[*]:-nothing}"
  exit 0
fi
[ ${#need[@]} -eq 0 ] && exit 0
if ! command -v apt-get >/dev/null 2>&1; then
  echo "pbdyn: missing system packages (${need[*]}); install them with your package manager ($why)" >&2
  exit 0
fi
SUDO=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
echo "pbdyn: installing ${need[*]}" >&2
$SUDO apt-get update -qq >/dev/null 2>&1 || true
$SUDO apt-get install -y -qq "${need[@]}" >/dev/null 2>&1 || echo "pbdyn: could not install ${need[*]}" >&2
