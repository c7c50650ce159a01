"""pbdyn.models: the project's URDF models (quadrotor, pillar, box, sphere), shipped as package data.

setup.cfg maps this folder onto the package ``pbdyn.models``; find a model with ``pbdyn.resources.urdf_path``.
This file only makes the folder a regular package, which setuptools' editable install needs to map it.
"""
