"""Shared fixtures: FMUs are built once per session into a private cache folder."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _private_fmu_cache(tmp_path_factory):
    """Build FMUs into a session folder, so tests never depend on (or pollute) ~/.cache."""
    previous = os.environ.get("LCMESH_CACHE_DIR")
    os.environ["LCMESH_CACHE_DIR"] = str(tmp_path_factory.mktemp("lcmesh-cache"))
    yield
    if previous is None:
        os.environ.pop("LCMESH_CACHE_DIR", None)
    else:
        os.environ["LCMESH_CACHE_DIR"] = previous


@pytest.fixture(scope="session")
def lcopt5():
    from lcmesh.twin.system import load_system

    return load_system("lcopt-5")


@pytest.fixture
def plant(lcopt5):
    from lcmesh.twin.plant import Plant

    with Plant(lcopt5) as p:
        yield p
