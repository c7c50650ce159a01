"""Build pbdyn's native ruckig batch (ruckig_batch.cpp) against the sources of the installed ruckig version.

``python -m pbdyn.planning.primitives.native.build`` downloads the installed ruckig version's source distribution from
the package index (or takes ``--sdist PATH``), compiles its trajectory calculator with this module's ruckig_batch.cpp
into one shared library next to this file (C++20 compiler: $CXX, else c++ / g++ / clang++; flags as ruckig's release
build, -O3 -DNDEBUG), runs it once on the probe inputs in a child process, and replaces an earlier build atomically,
recording its sha256 beside it (the planners load only a library that matches that record). `make` runs it; without a
compiler or the network the planners keep to the ruckig Python package (same results, slower). Exit status 0 on success,
1 with a one-line reason otherwise.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from pbdyn.files import atomic_write
from pbdyn.planning.primitives.native import LIBRARY, write_checksum

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "ruckig_batch.cpp"
_RUCKIG_SOURCES = ("brake", "position_first_step1", "position_first_step2", "position_second_step1",
                   "position_second_step2", "position_third_step1", "position_third_step2", "velocity_second_step1",
                   "velocity_second_step2", "velocity_third_step1", "velocity_third_step2")


class BuildError(RuntimeError):
    """The native library could not be built (the message says why, in one line)."""


def compiler() -> str:
    """The C++ compiler to use: $CXX if set, else the first of c++, g++, clang++ on PATH."""
    cxx = os.environ.get("CXX")
    if cxx:
        found = shutil.which(cxx)
        if not found:
            raise BuildError(f"the compiler CXX={cxx} was not found")
        return found
    for name in ("c++", "g++", "clang++"):
        found = shutil.which(name)
        if found:
            return found
    raise BuildError("no C++ compiler found (set CXX or install g++)")


def fetch_sdist(version: str, dest: Path) -> Path:
    """Download ruckig==version's source distribution into ``dest`` with pip; its path."""
    cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--no-binary", ":all:",
           f"ruckig=={version}", "-d", str(dest)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    found = sorted(dest.glob("ruckig-*.tar.gz"))
    if done.returncode != 0 or not found:
        last = (done.stderr.strip().splitlines() or ["no sdist downloaded"])[-1]
        raise BuildError(f"could not download ruckig=={version}'s sources: {last}")
    return found[0]


def build(sdist: Path | None = None, output: Path = LIBRARY) -> Path:
    """Compile the library into ``output`` (atomically) from ``sdist`` or the downloaded sources of the installed
    ruckig version; its path. Raises BuildError."""
    try:
        version = importlib.metadata.version("ruckig")
    except importlib.metadata.PackageNotFoundError as exc:
        raise BuildError("the ruckig Python package is not installed") from exc
    cxx = compiler()
    with tempfile.TemporaryDirectory(prefix="pbdyn-native-") as tmp:
        tmp_dir = Path(tmp)
        archive = Path(sdist) if sdist is not None else fetch_sdist(version, tmp_dir)
        if not archive.is_file():
            raise BuildError(f"sdist: no such file {archive}")
        with tarfile.open(archive) as tar:
            tar.extractall(tmp_dir / "src", filter="data")
        roots = [p.parent.parent for p in (tmp_dir / "src").glob("*/include/ruckig")]
        if len(roots) != 1:
            raise BuildError(f"sdist: {archive.name} holds no ruckig sources (include/ruckig)")
        root = roots[0]
        sources = [root / "src" / "ruckig" / f"{name}.cpp" for name in _RUCKIG_SOURCES]
        missing = [s.name for s in sources if not s.is_file()]
        if missing:
            raise BuildError(f"sdist: {archive.name} lacks {', '.join(missing)}")
        staged = tmp_dir / output.name
        cmd = [cxx, "-O3", "-DNDEBUG", "-std=c++20", "-fPIC", "-shared", f"-I{root / 'include'}",
               f'-DPBDYN_RUCKIG_VERSION="{version}"', str(SOURCE), *map(str, sources), "-o", str(staged)]
        try:
            done = subprocess.run(cmd, capture_output=True, text=True)
        except OSError as exc:
            raise BuildError(f"{Path(cxx).name} could not be run ({exc.strerror})") from exc
        if done.returncode != 0:
            first = next((ln for ln in done.stderr.splitlines() if "error" in ln), done.stderr.strip()[:200])
            raise BuildError(f"{Path(cxx).name} failed: {first}")
        probe(staged)
        try:
            atomic_write(output, lambda tmp: shutil.copyfile(staged, tmp), make_parents=True)
            write_checksum(output)
        except OSError as exc:
            raise BuildError(f"cannot write {output} ({exc.strerror})") from exc
    return output


def probe(path: Path) -> None:
    """Load the library at ``path`` and run it on the probe inputs in a child process (a broken library may end
    its process with a signal); BuildError if that child does not finish cleanly."""
    code = ("import sys; from pathlib import Path; from pbdyn.planning.primitives import native; "
            "native.agrees(native._load(Path(sys.argv[1])))")
    paths = (str(HERE.parents[3]), os.environ.get("PYTHONPATH"))     # the child imports this pbdyn
    env = dict(os.environ, PBDYN_NATIVE="0", PYTHONPATH=os.pathsep.join(p for p in paths if p))
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, env=env)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
        raise BuildError(f"the built library failed its probe run ({last})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pbdyn.planning.primitives.native.build",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--sdist", type=Path, default=None, help="ruckig source archive (default: download)")
    parser.add_argument("--output", type=Path, default=LIBRARY, help=f"library path (default: {LIBRARY})")
    args = parser.parse_args(argv)
    try:
        path = build(args.sdist, args.output)
    except BuildError as exc:
        print(f"pbdyn: native ruckig batch not built ({exc}); the planners use the ruckig Python package",
              file=sys.stderr)
        return 1
    print(f"pbdyn: built {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
