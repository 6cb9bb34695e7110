"""The shipped skill library: ``<library>/<skill>.npz`` + ``.json`` sidecars (docs/research/skills.md).

Installed with the package as package data, so it is found the same way in a checkout, an
editable install and a normal ``pip install .``: ``library_root()``. Loading skills from it is
``training.skill_library.load_skills``.
"""

from __future__ import annotations

import os


def library_root() -> str:
    """The directory holding the libraries (``kinematic/``, ``mjx/``)."""
    return os.path.dirname(os.path.abspath(__file__))
