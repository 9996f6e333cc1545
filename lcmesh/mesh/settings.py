"""Process settings of the mesh (``LCMESH_`` environment variables) and one config model per agent.

Every agent process reads the same ``MeshSettings``: which site it serves, where the router is,
which plant and trace the twin runs, where history goes. Per-agent knobs live in nested models,
set from the environment with a double underscore: ``LCMESH_SENSOR__DEADLINE_FRACTION=0.5``.
Lists accept JSON or commas: ``LCMESH_ROUTER_ENDPOINTS=tcp/10.0.0.2:7447,tcp/10.0.0.3:7447``.

What operators change at run time (controller, guardrail limits, LLM settings, speed factor) is
not here: the Configuration agent holds it (``lcmesh.mesh.messages.MeshConfig``); these settings
only seed its first version.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/\S+$")
DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
PER_PROCESS = ("bus_password", "bus_password_file")  # one process's own secret: never in a child's environment
MIN_VALVE_EXERCISE_S = 60.0  # four 15 s plant steps: one stroke must fit in a period


def check_valve_exercise_s(value: float) -> float:
    """0 (off) or at least ``MIN_VALVE_EXERCISE_S``; a shorter period is refused, not silently raised."""
    if 0 < value < MIN_VALVE_EXERCISE_S:
        raise ValueError(f"`valve_exercise_s` must be 0 (off) or >= {MIN_VALVE_EXERCISE_S:g} s (a stroke lasts four "
                         f"15 s plant steps), got {value:g}")  # fmt: skip
    return value


def _split_list(value: object) -> object:
    if isinstance(value, str):
        text = value.strip()
        if text.startswith("["):
            import json

            return json.loads(text)
        return [part.strip() for part in text.split(",") if part.strip()]
    return value


def _check_endpoints(field: str, endpoints: list[str]) -> list[str]:
    for endpoint in endpoints:
        if not _ENDPOINT.match(endpoint):
            raise ValueError(
                f"`{field}` entries must look like 'tcp/HOST:PORT' (or udp/, tls/, quic/, ws/), got {endpoint!r}"
            )
    return endpoints


EndpointList = Annotated[list[str], NoDecode]
PluginList = Annotated[list[str], NoDecode]


class _Component(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SensorConfig(_Component):
    """The Sensor agent: owns the twin, applies actions."""

    deadline_fraction: float = Field(0.8, gt=0, le=1, description="wait this share of a period for a proposal")
    hold_periods: int = Field(2, ge=0, description="missed periods that hold the last safe action before G36")
    spinup_hours: float = Field(1.0, ge=0, description="twin spin-up at the trace's first row before step 0")
    checkpoint_every_steps: int = Field(1, ge=1, description="serialized FMU state saved with the step's rows")
    payload_every_steps: int | None = Field(
        None, ge=1, description="full state JSON in history every N steps (None: 1, or 40 above 5,000 values)"
    )
    resume: bool = Field(True, description="continue an unfinished run of the same system and trace from history")
    loop: str = Field("plant", pattern=NAME_PATTERN, description="control loop whose proposals it applies")
    # a what-if holds the twin while it runs (the longest, 2880 steps twice, ~0.2 s): at 1 a second for each of
    # the two what-if tools a flood holds it at most ~0.4 s a second; a chat answer's few what-ifs fit the burst
    tools_rate_per_s: float = Field(1.0, gt=0, le=10_000, description="queries a second each tools/{name} "
                                    "queryable answers each asking role once its burst is spent; more get 'rate "
                                    "limited'")  # fmt: skip
    tools_burst: int = Field(10, ge=1, le=100_000, description="queries each tools/{name} queryable answers each "
                             "asking role at once")  # fmt: skip
    # what-ifs together, whoever asks: the largest (a controller what-if, 60 min twice) is 120 plant minutes
    whatif_max_running: int = Field(2, ge=1, le=64, description="what-ifs running or waiting for the twin at once; "
                                    "more are refused 'rate limited' (HTTP 429 through the UI)")  # fmt: skip
    whatif_plant_minutes_per_min: float = Field(240.0, gt=0, le=1e6, description="plant minutes the what-ifs "
                                                "may run per wall minute, all askers together (a larger one is "
                                                "refused)")  # fmt: skip


class ControlConfig(_Component):
    """The Control agent: runs the configured policy."""

    loop: str = Field("plant", pattern=NAME_PATTERN)
    explain: bool = Field(True, description="publish an explanation (facts + text) for every decision")
    explainer: Literal["renderer", "llm"] = Field(
        "llm", description="who writes the text: the toolbox renderer for every decision, and by default the local "
        "LLM's text for the newest one, with the toolbox's what-if facts, published over the rendering only where the "
        "judge verified a what-if claim the rendering lacks (docs/llm.md; renderer: the rendering alone)")
    explain_level: Literal["short", "detailed"] = Field(
        "short", description="the LLM's level (explainer = llm): short (the rendering and the LLM's what-if, 3 s "
        "budget) or detailed (the LLM's whole text, 10 s budget)")
    inline: bool = Field(True, description="decide in the bus callback (lowest latency); false: in a worker "
                         "thread with a one-item mailbox, for policies slower than a control period")


class MaintenanceConfig(_Component):
    """The Maintenance agent: wraps the toolbox's fault detector."""

    clear_after_updates: int = Field(3, ge=1, description="a finding must be absent this many updates to clear")
    detector_poll_s: float = Field(5.0, gt=0, description="retry importing the detector this often until it exists")


class MonitorConfig(_Component):
    """The Agent Monitor."""

    report_period_s: float = Field(1.0, gt=0)
    stale_after_s: float = Field(3.0, gt=0, description="alive but no stats this long: reported as hung")
    cpu_high_pct: float = Field(90.0, gt=0)
    rss_high_bytes: int = Field(1 << 30, gt=0)


class HistoryConfig(_Component):
    """History retention, applied by the Sensor (docs/mesh.md, History). Ages are wall-clock hours, 0: no age limit."""

    max_mb: float = Field(200.0, ge=0, description="bound on history.sqlite plus its -wal in MB (10^6 bytes); 0: none")
    keep_payload_hours: float = Field(24.0, ge=0, description="full state JSON and explanation facts; then thinned")
    keep_states_hours: float = Field(168.0, ge=0, description="plant_states summary rows")
    keep_decisions_hours: float = Field(720.0, ge=0, description="actions and explanation texts")
    keep_audit_hours: float = Field(2160.0, ge=0, description="alerts, config changes (the newest is always kept), "
                                    "agent events")
    keep_latest_steps: int = Field(240, ge=1, description="newest steps of an open run never thinned or pruned")
    prune_every_steps: int = Field(10, ge=1, description="a retention pass every N Sensor steps")
    batch_rows: int = Field(25, ge=1, description="rows per DELETE/UPDATE transaction of a pass (its -wal share)")
    pass_budget_ms: float = Field(20.0, gt=0, description="a pass starts no new batch after this; the rest waits")

    @model_validator(mode="after")
    def _tiers(self) -> "HistoryConfig":
        tiers = ("keep_payload_hours", "keep_states_hours", "keep_decisions_hours", "keep_audit_hours")
        for shorter, longer in zip(tiers, tiers[1:]):
            a, b = getattr(self, shorter), getattr(self, longer)
            if b and (not a or a > b):  # 0 is "no limit", the longest
                raise ValueError(f"`{longer}` must be 0 (no limit) or >= `{shorter}` "
                                 f"({f'{a:g}' if a else '0, no limit'}), got {b:g}: each tier is kept at least "
                                 "as long as the one before")  # fmt: skip
        return self


class ConfigurationConfig(_Component):
    """The Configuration agent."""

    store_path: Path | None = Field(None, description="persisted config JSON (default: DATA_DIR/config.json)")


class OrchestrationConfig(_Component):
    """The Orchestration agent: starts and supervises the other agents."""

    roles: list[str] = ["configuration", "sensor", "control", "maintenance", "monitor", "ui"]
    supervise: bool = Field(True, description="start the roles as child processes and restart them")
    hung_after_s: float = Field(2.0, gt=0, description="alive but silent (no stats) this long: killed, restarted")
    backoff_initial_s: float = Field(0.2, ge=0)
    backoff_max_s: float = Field(10.0, gt=0)
    healthy_after_s: float = Field(30.0, gt=0, description="up this long resets the backoff")
    stop_timeout_s: float = Field(5.0, gt=0)


class MeshSettings(BaseSettings):
    """Settings every mesh process reads from ``LCMESH_*`` variables."""

    model_config = SettingsConfigDict(env_prefix="LCMESH_", env_nested_delimiter="__", extra="ignore")

    site: str = Field("default", pattern=NAME_PATTERN, description="key prefix lcmesh/{site}/...")
    router_endpoints: EndpointList = Field([DEFAULT_ROUTER], description="routers a client connects to")
    listen_endpoints: EndpointList = Field([DEFAULT_ROUTER], description="where `lcmesh router` listens")
    router_peers: EndpointList = Field([], description="other routers a router links to (scale-out)")
    lease_ms: int = Field(1500, ge=200, le=60_000, description="a silent session is dropped after this")
    connect_timeout_s: float = Field(30.0, ge=0, description="agents retry the router this long, then exit")
    bus_auth: bool = Field(True, description="user/password per role and the router's access control (docs/mesh.md, "
                           "Security); off only for a router on loopback")
    secrets_dir: Path | None = Field(None, description="the run's secrets, one folder per role, and TLS files "
                                     "(default DATA_DIR/secrets; docs/mesh.md, Security)")
    bus_password: SecretStr | None = Field(None, description="this process's bus password instead of the file in "
                                           "SECRETS_DIR (an agent on another host)")
    bus_password_file: Path | None = Field(None, description="the file holding this process's bus password (what "
                                           "`lcmesh demo` gives each child: its own role's file alone)")
    bus_tls_hosts: EndpointList = Field([], description="extra names the router certificate is valid for (tls/ "
                                         "endpoints)")
    system: str = "lcopt-5"
    trace: str = "frontier-2024-04-07"
    scenario: str = Field("frontier", description="how the trace drives the plant: frontier, design-day or lcopt "
                          "(docs/traces.md, Scenarios)")
    wet_bulb_offset_k: float = Field(0.0, ge=-50, le=50, description="K added to the wet bulb, on top of the "
                                     "scenario's")
    speed_factor: float = Field(60.0, gt=0, le=100_000, description="simulated seconds per wall second")
    controller: str = Field("tree", description="the controller at start: the trees distilled from the real-load "
                            "plant's case-7 policy (docs/controllers.md)")
    controller_plugins: PluginList = Field([], description="third-party controllers ('package.module:Class') the "
                                           "configuration may switch to; any other module:Class name is refused "
                                           "(docs/controllers.md, Bring your own controller)")  # fmt: skip
    valve_exercise_s: float = Field(0.0, ge=0, le=86_400, description="stroke each CDU primary valve this often "
                                    "(plant seconds, 0: off); the initial config value")
    data_dir: Path = Path("runs/mesh")
    history_path: Path | None = None
    history: HistoryConfig = HistoryConfig()
    ui_host: str = "127.0.0.1"
    ui_port: int = Field(8000, ge=1, le=65535)
    api_token_file: Path | None = None
    stats_period_s: float = Field(0.5, gt=0, description="agents publish their stats this often")
    log_level: str = "INFO"

    sensor: SensorConfig = SensorConfig()
    control: ControlConfig = ControlConfig()
    maintenance: MaintenanceConfig = MaintenanceConfig()
    monitor: MonitorConfig = MonitorConfig()
    configuration: ConfigurationConfig = ConfigurationConfig()
    orchestration: OrchestrationConfig = OrchestrationConfig()

    _valve_exercise = field_validator("valve_exercise_s")(check_valve_exercise_s)

    @field_validator("scenario")
    @classmethod
    def _known_scenario(cls, name: str) -> str:
        from lcmesh.twin.traces import scenario_named

        return scenario_named(name).name

    @field_validator("router_endpoints", "listen_endpoints", "router_peers", "bus_tls_hosts", "controller_plugins",
                     mode="before")  # fmt: skip
    @classmethod
    def _lists(cls, value: object) -> object:
        return _split_list(value)

    @field_validator("controller_plugins")
    @classmethod
    def _plugin_names(cls, names: list[str]) -> list[str]:
        if not names:
            return names
        from lcmesh.twin.controllers import PLUGIN_PATTERN

        for name in names:
            if not re.match(PLUGIN_PATTERN, name):
                raise ValueError(f"`controller_plugins` entries must look like 'package.module:Class', got {name!r}")
        return names

    @model_validator(mode="after")
    def _endpoints(self) -> "MeshSettings":
        _check_endpoints("router_endpoints", self.router_endpoints)
        _check_endpoints("listen_endpoints", self.listen_endpoints)
        _check_endpoints("router_peers", self.router_peers)
        if not self.router_endpoints:
            raise ValueError("`router_endpoints` must name at least one router, e.g. 'tcp/127.0.0.1:7447'")
        return self

    @property
    def allowed_controller_plugins(self) -> list[str]:
        """Third-party controllers the mesh may load: ``controller_plugins`` and this process's own ``controller``."""
        own = [self.controller] if ":" in self.controller else []
        return [*self.controller_plugins, *own]

    @property
    def history_file(self) -> Path:
        """The SQLite history file (``history_path``, else ``data_dir/history.sqlite``)."""
        return self.history_path or self.data_dir / "history.sqlite"

    @property
    def secrets_path(self) -> Path:
        """The run's bus secrets (``secrets_dir``, else ``data_dir/secrets``)."""
        return self.secrets_dir or self.data_dir / "secrets"

    @property
    def log_dir(self) -> Path:
        return self.data_dir / "logs"

    def to_env(self) -> dict[str, str]:
        """These settings as ``LCMESH_*`` variables, for child processes (nested configs as JSON)."""
        env = {}
        for name, value in self:
            if value is None or name in PER_PROCESS:
                continue
            if isinstance(value, BaseModel):
                text = value.model_dump_json()
            elif isinstance(value, list):
                text = ",".join(value)
            elif isinstance(value, bool):
                text = "true" if value else "false"
            else:
                text = str(value)
            env[f"LCMESH_{name.upper()}"] = text
        return env


def endpoint_env(endpoints: list[str]) -> str:
    """The value of an endpoint-list variable for a child process's environment."""
    return ",".join(endpoints)
