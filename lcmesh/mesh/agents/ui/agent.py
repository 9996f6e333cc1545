"""The UI agent: follows everything on the bus and serves the REST API, live page, chat and /metrics.

``start`` resolves the API token (refusing an insecure bind), binds the HTTP socket (so a port
in use fails the start with a clear message), subscribes to plant state, applied actions,
explanations, alerts, the monitor report, agent events, agent stats and liveliness, and serves
uvicorn in a thread on ``LCMESH_UI_HOST:LCMESH_UI_PORT``. History is read from the SQLite file
(opened when the Sensor has created it); config and control go through the Configuration
agent's queryables, what-ifs through the Sensor's toolbox queryable.
"""

from __future__ import annotations

import logging
import socket
import threading
import time

from lcmesh.mesh import keys
from lcmesh.mesh.agents.base import Agent
from lcmesh.assistant.sources import ChatSources, NotReady
from lcmesh.mesh.agents.ui.app import UiContext, create_app
from lcmesh.assistant.engine import ChatEngine
from lcmesh.mesh.agents.ui.config import UiSettings
from lcmesh.mesh.agents.ui.gateway import MeshGateway
from lcmesh.mesh.agents.ui.live import EventHub, LiveStore, dumps
from lcmesh.assistant.phrasing import make_phraser
from lcmesh.assistant.plan import make_planner
from lcmesh.mesh.agents.ui.security import is_loopback, resolve_token, weak_token_reason
from lcmesh.mesh.bus import QueryError
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import (
    AgentEvent, Alert, AppliedAction, ConfigDoc, Explanation, MeshConfig, MonitorReport, PlantState,
    utc_now,
)  # fmt: skip
from lcmesh.mesh.ratelimit import TokenBuckets
from lcmesh.mesh.tools import registry
from lcmesh.twin.system import load_system

log = logging.getLogger("lcmesh.mesh.agents.ui")
START_TIMEOUT_S = 15.0


class UiAgent(Agent):
    role = "ui"

    def __init__(self, settings, agent_id: str | None = None, ui: UiSettings | None = None):
        super().__init__(settings, agent_id)
        self.ui = ui
        self.ctx: UiContext | None = None
        self.server = None
        self._reader: HistoryReader | None = None
        self._reader_lock = threading.Lock()

    @property
    def url(self) -> str:
        return f"http://{self.settings.ui_host}:{self.settings.ui_port}"

    # --- lifecycle ------------------------------------------------------------------------------
    def on_start(self) -> None:
        import uvicorn

        s = self.settings
        ui = self.ui = self.ui or UiSettings()
        token = resolve_token(ui.api_token.get_secret_value() if ui.api_token else None, s.api_token_file,
                              s.ui_host, s.data_dir, create_file=ui.create_token_file)  # fmt: skip
        if token.origin == "generated":
            log.warning("no LCMESH_API_TOKEN set: writes need the random token written to %s", token.path)
        elif token.origin == "file" and s.api_token_file is None:
            log.warning("no LCMESH_API_TOKEN set: writes need the token kept in %s", token.path)
        elif weak_token_reason(token.value) and is_loopback(s.ui_host):
            log.warning("the API token is weak (%s); acceptable on loopback only", weak_token_reason(token.value))
        sock = _bind(s.ui_host, s.ui_port)
        system = load_system(s.system)
        hub = EventHub(ui.sse_queue, ui.sse_max_clients)
        store = LiveStore(system, hub, keep=ui.decisions_kept, state_hz=ui.sse_state_hz)
        gateway = MeshGateway(self.bus, self.site, ui.bus_timeout_s)
        phraser, note = make_phraser(ui.phraser, adapter=ui.phraser_adapter)
        planner = make_planner(ui.planner)
        if hasattr(planner, "warm"):  # the local model loads beside the UI, not inside the first question
            planner.warm()
        sources = ChatSources(system=system, state=lambda: store.state, history=self.history_reader,
                              config=lambda: self.config_doc, agents=store.agents_view, gateway=gateway,
                              applied=store.latest_applied)  # fmt: skip
        self.ctx = UiContext(settings=s, ui=ui, system=system, store=store, hub=hub, token=token,
                             history=self.history_reader, config_doc=lambda: self.config_doc, gateway=gateway,
                             chat=ChatEngine(sources, phraser, planner=planner, session_s=ui.chat_session_s,
                                             check=ui.chat_check),
                             agent_id=self.agent_id, phraser_note=note)  # fmt: skip
        self._serve_data_tools(sources)
        self._preload_alerts(store)
        self.watch_config(self._on_config)
        self.subscribe(keys.applied_all(self.site), AppliedAction, store.on_applied)
        self.subscribe(keys.plant_state(self.site), PlantState, store.on_state, latest=True)
        self.subscribe(keys.explain_all(self.site), Explanation, store.on_explanation)
        self.subscribe(keys.alerts(self.site), Alert, store.on_alert)
        self.subscribe(keys.monitor_report(self.site), MonitorReport, store.on_monitor, latest=True)
        self.subscribe(keys.events(self.site), AgentEvent, store.on_event)
        self.subscribe_stats(store.on_stats)  # attributed by key: a forged `decided_by` never reaches the page
        self.watch_agents(lambda role, agent_id, alive: store.on_liveliness(role, agent_id, alive, utc_now()))
        # uvicorn trusts X-Forwarded-For from 127.0.0.1 by default: any local client could name its own address (a
        # fresh chat bucket per request, the `changed_by` it likes); only a configured proxy's headers count
        config = uvicorn.Config(create_app(self.ctx), log_level="warning", access_log=False, lifespan="on",
                                timeout_graceful_shutdown=2, ws="none", proxy_headers=bool(ui.trusted_proxies),
                                forwarded_allow_ips=ui.trusted_proxies or None)  # fmt: skip
        self.server = uvicorn.Server(config)
        self.spawn("http", lambda: self.server.run(sockets=[sock]))
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self.server.started:
            if self.failed.is_set() or time.monotonic() > deadline:
                raise RuntimeError(f"the HTTP server did not start on {self.url}")
            time.sleep(0.02)
        log.info("UI on %s (token from %s)", self.url, token.origin)

    def stop(self) -> None:
        if self.server is not None:
            self.server.should_exit = True
            if self.ctx is not None:
                self.ctx.hub.end()
        super().stop()

    def on_stop(self) -> None:
        with self._reader_lock:
            if self._reader is not None:
                self._reader.close()
                self._reader = None

    def details(self) -> dict:
        ctx = self.ctx
        if ctx is None:
            return {}
        return {"url": self.url, "live_clients": ctx.hub.clients, "states": ctx.store.counts.get("states", 0),
                "chat": dict(ctx.chat.intents), "chat_ungrounded": ctx.chat.ungrounded,
                "chat_planned_by": dict(ctx.chat.planned_by), "phraser": ctx.chat.phraser.name,
                "phraser_note": ctx.phraser_note}  # fmt: skip

    def _serve_data_tools(self, sources: ChatSources) -> None:
        """The operator's data tools on ``tools/{name}/{role}``: the registry the chat plans with, for anyone on the
        bus, each with a token bucket per tool and asking role (history reads are cheap, but not free)."""
        context = registry.ToolContext(system=sources.system, data=sources)
        limit = TokenBuckets(self.ui.tools_rate_per_s, self.ui.tools_burst)
        for name in registry.served_tools(data=True):

            def answer(payload: bytes | None, name=name):
                result = registry.invoke(name, payload or b"{}", context)
                if not result.ok:
                    raise QueryError(result.error)
                return result

            self.serve(keys.tool_served(self.site, name), answer, limit=limit)

    # --- data sources --------------------------------------------------------------------------------
    def history_reader(self) -> HistoryReader:
        """The history file, opened read-only once the Sensor has created it; NotReady until then."""
        with self._reader_lock:
            if self._reader is None:
                path = self.settings.history_file
                if not path.exists():
                    raise NotReady(f"no history file yet at {path} (the Sensor agent creates it)")
                self._reader = HistoryReader(path)
            return self._reader

    def _preload_alerts(self, store: LiveStore) -> None:
        """Alerts still active in history, so counts and the page are right after a restart."""
        try:
            rows = self.history_reader().alerts(active_only=True, limit=1000)
        except (NotReady, OSError):
            return
        for row in reversed(rows):
            try:
                store.alerts[row["alert_id"]] = Alert.model_validate({**{k: row[k] for k in (
                    "alert_id", "state", "kind", "severity", "location", "message", "evidence", "prescription",
                    "predicted_failure_s", "step", "time_s", "source")}})  # fmt: skip
            except Exception as exc:  # an odd row must not stop the UI
                log.debug("skipped alert row %s: %s", row.get("alert_id"), exc)

    # --- bus callbacks -------------------------------------------------------------------------------
    def _on_config(self, _old: MeshConfig, _new: MeshConfig) -> None:
        doc: ConfigDoc | None = self.config_doc
        if doc is not None and self.ctx is not None:
            self.ctx.hub.publish("config", dumps(doc.model_dump(mode="json")))


def _bind(host: str, port: int) -> socket.socket:
    """A bound TCP socket for uvicorn; OSError naming LCMESH_UI_HOST/PORT if that fails."""
    try:
        family, kind, proto, _name, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.socket(family, kind, proto)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
    except OSError as exc:
        from lcmesh.mesh.service import port_held_message

        held = port_held_message(port, "the UI")
        raise OSError(f"the UI can not listen on {host}:{port} ({held or exc}); set LCMESH_UI_HOST / LCMESH_UI_PORT "
                      "or stop what holds the port") from None
    sock.set_inheritable(True)
    return sock
