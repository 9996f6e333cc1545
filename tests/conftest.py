"""Shared fixtures: FMUs are built once per session into a private cache folder; no test leaves a thread running."""

from __future__ import annotations

import os
import threading

import pytest

# The UIs the tests start plan chat questions with the regex rules: loading the local planner model in every
# test mesh (and compose process) would cost minutes of the two cores; tests/llm/test_planner.py and
# `lcmesh bench chat` exercise the LLM planner itself.
os.environ.setdefault("LCMESH_UI_PLANNER", "rules")
# Likewise the Control agents explain with the renderer alone: the LLM explainer keeps a core busy while a mesh runs;
# tests/mesh/agents/test_sensor_control.py and `lcmesh bench chat --live` exercise it in an agent and in the demo.
os.environ.setdefault("LCMESH_CONTROL__EXPLAINER", "renderer")
# One intra-op thread for torch here and in every process a test starts (the variable is inherited). The tier must
# pass on a machine whose two cores are busy with other work, and there torch's default of one thread per core
# oversubscribes them: its threads wait at every operation's barrier for a sibling the scheduler has parked. Measured
# with two busy loops on 2 cores: a shipped policy's floor test took 23 s inside the tier (0.8 s on a quiet machine),
# and 1.5 s alone with one thread against 3.8 s with two. The tests check decisions, not parallel speed.
os.environ.setdefault("OMP_NUM_THREADS", "1")
# Benchmarks' units run one after another here: a Ray instance per bench test would cost seconds of the two cores each;
# tests/bench/test_engine.py starts Ray and checks that it gives the serial run's table, row for row.
os.environ.setdefault("LCMESH_BENCH_ENGINE", "serial")
THREAD_EXIT_GRACE_S = 10.0  # a thread told to stop may still be on its way out when its owner returns
_STARTED_BY: dict[threading.Thread, str] = {}  # a thread found running after a test -> that test's id


def _running_threads(exclude: set[threading.Thread]) -> list[threading.Thread]:
    """Non-daemon Python threads alive now, besides ``exclude``.

    Daemon threads are left out: foreign threads that call into Python (zenoh's callbacks) show up
    as daemon ``_DummyThread`` objects that never end, and the agents' own threads are daemons that
    ``Agent.stop`` joins.
    """
    return [t for t in threading.enumerate() if t not in exclude and not t.daemon and t.is_alive()]


def _fail_if_left(threads: list[threading.Thread], where: str) -> None:
    for thread in threads:
        thread.join(THREAD_EXIT_GRACE_S / len(threads))
    left = [f"{t.name} (running since {_STARTED_BY.get(t, 'a fixture')})" for t in threads if t.is_alive()]
    if left:
        pytest.fail(f"{where} left threads running: {', '.join(left)}; join every thread a test starts",
                    pytrace=False)  # fmt: skip


@pytest.fixture(autouse=True)
def _note_threads_a_test_leaves(request):
    """Remember which test started a thread that outlives it (a module fixture's pool may, until the module ends)."""
    before = set(threading.enumerate())
    yield
    for thread in _running_threads(before):
        _STARTED_BY.setdefault(thread, request.node.nodeid)


@pytest.fixture(scope="module", autouse=True)
def _no_thread_left_by_the_module(request):
    """Fail a test module whose tests or fixtures leave a non-daemon thread running after its fixtures are gone."""
    before = set(threading.enumerate())
    yield
    # zenoh's callback threads belong to a session; a session-scoped fixture (the UI tests' mesh) keeps its own
    # until the session ends, where the check below still sees them
    left = [t for t in _running_threads(before) if not t.name.endswith("(pyo3-closure)")]
    if left:
        _fail_if_left(left, request.module.__name__)


@pytest.fixture(scope="session", autouse=True)
def _no_thread_left_by_the_session():
    """Fail the session when its fixtures leave non-daemon threads running at its end."""
    yield
    left = _running_threads({threading.main_thread()})
    if left:
        _fail_if_left(left, "the session's fixtures")


@pytest.fixture(autouse=True)
def _private_result_cache(tmp_path, monkeypatch):
    """Each test's benchmark units cache into its own file: no test reads another's (or the repo's) results."""
    monkeypatch.setenv("LCMESH_BENCH_CACHE", str(tmp_path / "units.sqlite"))


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
    """(out, action, previous action, wet bulb) of G36's decision `steps` steps into the Frontier day (the mesh's
    default scenario: real loads and wet bulb).

    `out` and the actions are copies, valid after the plant is closed.
    """
    import numpy as np

    from lcmesh.twin.controllers import Observation, make_controller
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import FRONTIER_DAY, load_trace

    trace = load_trace(FRONTIER_DAY, system)
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
