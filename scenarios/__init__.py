"""pbdyn.scenarios: the bundled scenarios, datasets and example worlds, shipped as package data.

setup.cfg maps this folder onto the package ``pbdyn.scenarios``; find a scenario with
``pbdyn.resources.bundled_scenario`` (``pbdyn run quickstart`` does). This file only makes the folder a regular
package, which setuptools' editable install needs to map it.
"""
