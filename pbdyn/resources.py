"""Where pbdyn's bundled files are: the URDF models (urdf/) and the bundled scenarios (scenarios/).

In a source checkout, and in an editable install of one, they are the checkout's top-level folders; in an
installed wheel they are the data packages ``pbdyn.models`` and ``pbdyn.scenarios`` that setup.cfg maps those
folders onto. Every lookup of a bundled file goes through this module.
"""

from __future__ import annotations

import functools
import importlib.resources
from pathlib import Path

from pbdyn.errors import ConfigError, PbdynError

_CHECKOUT = Path(__file__).resolve().parent.parent
_FOLDERS = {"pbdyn.models": "urdf", "pbdyn.scenarios": "scenarios"}


@functools.cache
def _folder(package: str) -> Path:
    # A checkout's own folders first: running a checkout must never pick up another installation's data.
    local = _CHECKOUT / _FOLDERS[package]
    if (_CHECKOUT / "setup.cfg").is_file() and local.is_dir():
        return local
    try:
        root = importlib.resources.files(package)
    except ModuleNotFoundError:
        raise PbdynError(f"pbdyn is installed without its data package {package} (reinstall pbdyn)") from None
    if not isinstance(root, Path):
        raise PbdynError(f"pbdyn's data package {package} is not on the file system ({root}); install pbdyn unzipped")
    return root


def models_dir() -> Path:
    """The folder of the project's URDF models."""
    return _folder("pbdyn.models")


def scenarios_dir() -> Path:
    """The folder of the bundled scenarios (``*.toml``, ``datasets/``, ``worlds/``)."""
    return _folder("pbdyn.scenarios")


def urdf_path(name: str) -> Path:
    """The bundled URDF model ``name`` ("pillar" or "pillar.urdf"); ConfigError if there is none."""
    path = models_dir() / (name if name.endswith(".urdf") else f"{name}.urdf")
    if not path.is_file():
        raise ConfigError("urdf", "no bundled URDF model of that name", name)
    return path


def bundled_scenarios() -> list[str]:
    """Names of the bundled scenarios, e.g. "quickstart", "datasets/controlled_2d", "worlds/warehouse_2d"."""
    root = scenarios_dir()
    return sorted(p.relative_to(root).with_suffix("").as_posix() for p in root.rglob("*.toml"))


def bundled_scenario(name: str) -> Path | None:
    """The bundled scenario ``name`` ("quickstart", "quickstart.toml", "worlds/warehouse_2d"), None if none."""
    rel = Path(name)
    if rel.is_absolute() or not rel.parts or ".." in rel.parts:
        return None
    if rel.suffix != ".toml":
        rel = rel.with_name(rel.name + ".toml")
    path = scenarios_dir() / rel
    return path if path.is_file() else None


def find_scenario(path: str | Path) -> Path:
    """The scenario file ``path`` names: an existing file (``path``, or ``path`` + ".toml") always wins, else a
    bundled scenario of that name; ConfigError naming it otherwise."""
    p = Path(path)
    local = [p] if p.suffix == ".toml" or not p.name else [p, p.with_name(p.name + ".toml")]
    for cand in local:
        if cand.is_file():
            return cand
    bundled = bundled_scenario(str(path))
    if bundled is not None:
        return bundled
    tops = ", ".join(n for n in bundled_scenarios() if "/" not in n)
    raise ConfigError("scenario", f"file not found, nor a bundled scenario (bundled: {tops}, datasets/..., worlds/...)",
                      str(path))
