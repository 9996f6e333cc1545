"""Key expressions of the bus, built here and nowhere else (DESIGN.md, Bus conventions).

Every key starts with ``lcmesh/{site}/``, so several sites share one mesh without seeing each
other's traffic. Names inside keys (site, loop, agent id, role, tool) are checked: a ``*``, ``$``
or ``/`` would turn a key into a wildcard or shift its segments.
"""

from __future__ import annotations

import re

ROOT = "lcmesh"
_SEGMENT = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


def segment(value: str, what: str = "name") -> str:
    """`value` if it is a valid single key segment, else a ValueError naming `what`."""
    if not isinstance(value, str) or not _SEGMENT.match(value):
        raise ValueError(
            f"`{what}` must be 1-64 letters, digits, '_', '.' or '-' starting with a letter or digit, got {value!r}"
        )
    return value


def site_prefix(site: str) -> str:
    return f"{ROOT}/{segment(site, 'site')}"


def plant_state(site: str) -> str:
    """The Sensor publishes every plant step here (and answers GETs with the latest)."""
    return f"{site_prefix(site)}/plant/state"


def proposal(site: str, loop: str = "plant") -> str:
    return f"{site_prefix(site)}/control/{segment(loop, 'loop')}/proposal"


def applied(site: str, loop: str = "plant") -> str:
    return f"{site_prefix(site)}/control/{segment(loop, 'loop')}/applied"


def applied_all(site: str) -> str:
    """Applied actions of every loop of a site."""
    return f"{site_prefix(site)}/control/*/applied"


def explain(site: str, decision_id: str) -> str:
    return f"{site_prefix(site)}/explain/{segment(decision_id, 'decision_id')}"


def explain_all(site: str) -> str:
    return f"{site_prefix(site)}/explain/*"


def alerts(site: str) -> str:
    return f"{site_prefix(site)}/maintenance/alerts"


def monitor_report(site: str) -> str:
    return f"{site_prefix(site)}/monitor/report"


def agent_stats(site: str, agent_id: str) -> str:
    """Each agent's own counters, CPU and memory (read by the Agent Monitor and the Orchestrator)."""
    return f"{site_prefix(site)}/monitor/stats/{segment(agent_id, 'agent_id')}"


def agent_stats_all(site: str) -> str:
    return f"{site_prefix(site)}/monitor/stats/*"


def events(site: str, role: str = "*") -> str:
    """Agent events: started, died, restarted, exceptions (shown by the UI, recorded by the Sensor).

    Each role publishes on ``events/{role}``, the only events key the router lets it publish on, so the
    history's writer knows which role sent an event; without `role`, the events of every role.
    """
    return f"{site_prefix(site)}/events/{role if role == '*' else segment(role, 'role')}"


def recent_events(site: str, role: str = "*") -> str:
    """Queryable: a role's latest events (``RecentEvents``), for the history's writer after it starts."""
    return f"{events(site, role)}/recent"


def config(site: str, name: str = "all") -> str:
    """Configuration queryable; the Configuration agent also publishes each new version on ``config/all``."""
    return f"{site_prefix(site)}/config/{segment(name, 'config name')}"


CONFIGURING_ROLES = ("ui", "operator")
"""Bus roles the router lets reach ``configure/{role}/...`` (docs/mesh.md, Security)."""


def configure(site: str, role: str, name: str = "all") -> str:
    """Where `role` asks the Configuration agent for a change: the router lets only `role` reach it, so the
    key names the authenticated identity the audit records."""
    return f"{site_prefix(site)}/configure/{segment(role, 'role')}/{segment(name, 'config name')}"


def tool(site: str, name: str, role: str) -> str:
    """Where `role` asks tool `name`: the router lets only `role` reach it, so the host's rate limit is per role."""
    return f"{site_prefix(site)}/tools/{segment(name, 'tool')}/{segment(role, 'role')}"


def tool_served(site: str, name: str) -> str:
    """What a host serves for tool `name`: every role's ``tools/{name}/{role}``."""
    return f"{site_prefix(site)}/tools/{segment(name, 'tool')}/*"


def cmd(site: str, agent_id: str, verb: str) -> str:
    return f"{site_prefix(site)}/cmd/{segment(agent_id, 'agent_id')}/{segment(verb, 'verb')}"


def alive(site: str, role: str, agent_id: str) -> str:
    """Liveliness token of one agent."""
    return f"{site_prefix(site)}/alive/{segment(role, 'role')}/{segment(agent_id, 'agent_id')}"


def alive_role(site: str, role: str) -> str:
    """Liveliness tokens of every agent of one role."""
    return f"{site_prefix(site)}/alive/{segment(role, 'role')}/*"


def alive_all(site: str) -> str:
    return f"{site_prefix(site)}/alive/*/*"


def parse_alive(key: str) -> tuple[str, str] | None:
    """(role, agent_id) of a liveliness key, or None if `key` is not one."""
    parts = str(key).split("/")
    if len(parts) == 5 and parts[0] == ROOT and parts[2] == "alive":
        return parts[3], parts[4]
    return None


def all_keys(site: str) -> dict[str, str]:
    """Every key pattern of a site, for docs and tests."""
    return {
        "plant_state": plant_state(site),
        "proposal": f"{site_prefix(site)}/control/{{loop}}/proposal",
        "applied": f"{site_prefix(site)}/control/{{loop}}/applied",
        "explain": f"{site_prefix(site)}/explain/{{decision_id}}",
        "alerts": alerts(site),
        "monitor_report": monitor_report(site),
        "agent_stats": f"{site_prefix(site)}/monitor/stats/{{agent_id}}",
        "events": f"{site_prefix(site)}/events/{{role}}",
        "config": f"{site_prefix(site)}/config/{{name}}",
        "configure": f"{site_prefix(site)}/configure/{{role}}/{{name}}",
        "tool": f"{site_prefix(site)}/tools/{{tool}}/{{role}}",
        "cmd": f"{site_prefix(site)}/cmd/{{agent_id}}/{{verb}}",
        "alive": f"{site_prefix(site)}/alive/{{role}}/{{agent_id}}",
    }
