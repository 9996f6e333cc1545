"""The OpenAI-compatible client against a real local server (FastAPI + uvicorn on 127.0.0.1) serving the real model.

The clients wait as long as the test tier allows (``SLOW_MACHINE_S``): on a busy machine the server
answers late, never wrongly, and a client that gave up would leave the server decoding at teardown.
"""

from __future__ import annotations

import threading
import time

import httpx
import numpy as np
import pytest
import uvicorn

from lcmesh.llm.base import LlmBackendSettings, make_backend
from lcmesh.llm.controller import LlmController
from lcmesh.llm.server import create_app
from lcmesh.mesh.processes import free_port
from lcmesh.twin.controllers import Observation

SLOW_MACHINE_S = 600.0  # pytest's own timeout: no request gives up before the test would


@pytest.fixture(scope="module")
def server_url(base_backend):
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(base_backend), host="127.0.0.1", port=port, log_level="error"))
    thread = threading.Thread(target=server.run, name="test-llm-server")
    thread.start()
    try:
        while not server.started:
            assert thread.is_alive(), "the server thread ended before it started serving"
            time.sleep(0.05)
        yield f"http://127.0.0.1:{port}/v1"
    finally:
        server.should_exit = True
        thread.join()  # ends once a request in flight is answered: its decoding is bounded by max_tokens


@pytest.fixture
def client(server_url):
    backend = make_backend(backend="openai", base_url=server_url, model="smollm2", max_concurrency=5,
                           timeout_s=SLOW_MACHINE_S)  # fmt: skip
    yield backend
    backend.close()


def test_models_endpoint_names_the_served_model(server_url, base_backend):
    data = httpx.get(f"{server_url}/models", timeout=SLOW_MACHINE_S).json()
    assert data["data"][0]["id"] == base_backend.model_id


def test_client_gets_the_same_greedy_text_as_the_local_backend(client, base_backend):
    conv = [{"role": "user", "content": "Reply with a JSON object with key a and value 1."}]
    (local,) = base_backend.chat([conv], max_new_tokens=24, stop=["}"])
    (remote,) = client.chat([conv], max_new_tokens=24, stop=["}"])
    assert local.text.endswith("}")
    assert remote.text == local.text  # the server strips the stop string, the client puts it back
    assert remote.finish_reason == "stop" and remote.new_tokens == local.new_tokens
    assert remote.prompt_tokens == local.prompt_tokens


@pytest.mark.slow  # end to end (23 s); the HTTP path: test_client_gets_the_same_greedy_text_as_the_local_backend
def test_controller_over_http_decides_every_cabinet(client, plant, lcopt5):
    ctl = LlmController(lcopt5, backend=client, fallback="g36", period_steps=1, max_new_tokens=48,
                        decision_budget_s=SLOW_MACHINE_S)  # fmt: skip
    out = plant.reset()
    action = ctl.act(Observation(out, 291.15, np.full(lcopt5.n_blade_groups, 60e3), 0.0))
    s = ctl.stats_snapshot()
    assert (s["cabinet_decisions"], s["tower_decisions"]) == (5, 2)
    assert s["llm_cabinet_actions"] + s["llm_tower_actions"] + s["fallbacks"] == 7
    assert not {"backend", "timeout"} & set(s["fallback_reasons"])  # the endpoint answered; only parsing can reject
    assert np.isfinite(action.supply_temp_setpoint_k).all()


def test_dead_endpoint_is_an_error_generation_not_an_exception():
    settings = LlmBackendSettings(backend="openai", base_url=f"http://127.0.0.1:{free_port()}/v1", timeout_s=2)
    backend = make_backend(settings)
    (gen,) = backend.chat([[{"role": "user", "content": "hi"}]], max_new_tokens=4)
    backend.close()
    assert gen.finish_reason == "error"
    assert "Connect" in gen.error


def test_settings_reject_unknown_backend_with_a_hint():
    with pytest.raises(ValueError, match="did you mean 'openai'"):
        LlmBackendSettings(backend="opneai")
