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


def g36_decision_state(system, steps: int):
    """(out, action, previous action, wet bulb) of G36's decision `steps` steps into the Frontier day (+15 K).

    `out` and the actions are copies, valid after the plant is closed.
    """
    import numpy as np

    from lcmesh.twin.controllers import Observation, make_controller
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import FRONTIER_DAY, load_trace

    trace = load_trace(FRONTIER_DAY, system, wet_bulb_offset_k=15.0)
    controller = make_controller("g36", system)
    power = np.zeros(system.n_blade_groups)
    with Plant(system) as plant:
        out, previous = plant.out, None
        for k in range(steps):
            wet_bulb = float(trace.wet_bulb_k[k])
            action = controller.act(Observation(out, wet_bulb, trace.blade_power_w(k, out=power), k * 15.0))
            previous = action.copy()
            out = plant.step(power, wet_bulb, action)
        action = controller.act(Observation(out, wet_bulb, power, steps * 15.0)).copy()
        return {k: np.array(v) for k, v in out.items()}, action, previous, wet_bulb
