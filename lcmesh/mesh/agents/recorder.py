"""What the other agents publish, written to history by its one writer (the Sensor).

Only the Sensor opens a ``HistoryWriter``; the rows the others used to write themselves reach it
over the bus, on keys the router lets only the producing role publish (docs/mesh.md, Security):

| key | message | row | only published by |
|---|---|---|---|
| ``config/all`` | ``ConfigDoc`` (with its ``changes``) | ``config_changes`` | configuration |
| ``explain/*`` | ``Explanation`` | ``explanations`` | control |
| ``maintenance/alerts`` | ``Alert`` | ``alerts`` | maintenance |
| ``events/{role}`` | ``AgentEvent`` | ``agent_events`` | ``{role}`` |

A message whose ``source`` names an agent of another role than the key's is dropped and counted
(``foreign``): the router vouches for the key, not for what the message says about itself. A config
document must also pass the check every agent makes before adopting one (``Agent._unsigned``). What
is published while the Sensor is down: the current config document it reads when it starts, and every
agent's latest events (``events/{role}/recent``, the last ``RECENT_EVENTS`` of each) it fetches then
(an event already in history is not written twice); explanations and alerts need a plant step, so
none are made while it is down, and a config version superseded while it was down is not recorded.
The bus callbacks only queue a row; a thread of the Sensor writes them, so a step's transaction or a
retention pass never holds up the bus thread that brings proposals.
"""

from __future__ import annotations

import logging
import queue
from collections.abc import Callable

from lcmesh.mesh import keys
from lcmesh.mesh.bus import BusError
from lcmesh.mesh.history import HistoryWriter
from lcmesh.mesh.messages import AgentEvent, Alert, ConfigDoc, Explanation, RecentEvents
from lcmesh.mesh.security import ROLES, role_of_agent_id

log = logging.getLogger("lcmesh.mesh.agents.recorder")


class HistoryRecorder:
    """Subscribes an agent (the Sensor) to what the others publish and writes it with `writer`."""

    def __init__(self, writer: HistoryWriter):
        self.writer = writer
        self.tally = {"recorded": 0, "foreign": 0, "refused_configs": 0, "failed": 0}
        self._rows: queue.SimpleQueue[tuple[Callable, object]] = queue.SimpleQueue()
        self._unsigned: Callable[[ConfigDoc], str | None] = lambda doc: None

    def start(self, agent) -> None:
        """Declare the subscriptions and the writing thread through `agent` (both end when it stops)."""
        site, self._unsigned = agent.site, agent._unsigned
        w = self.writer
        agent.subscribe(keys.config(site, "all"), ConfigDoc, self._config, latest=True)
        agent.subscribe(keys.explain_all(site), Explanation, lambda msg: self._queue("control", msg, w.add_explanation))
        agent.subscribe(keys.alerts(site), Alert, lambda msg: self._queue("maintenance", msg, w.add_alert))
        agent.subscribe(keys.events(site), AgentEvent,
                        lambda msg, key: self._queue(key.rsplit("/", 1)[-1], msg, w.add_event), keyed=True)
        agent.spawn("record", lambda: self._write_loop(lambda: agent.stopping))
        agent.spawn("record-missed", lambda: self._fetch_recent_events(agent))

    def _fetch_recent_events(self, agent) -> None:
        """Queue every agent's latest events once (those sent while this writer was down among them); the role is
        the reply's key's, which the router lets only that role answer on."""
        w = self.writer
        try:  # one query per role: the router's ACL lets a role reply on its own key only, not to a wildcard query
            replies = [reply for role in ROLES
                       for reply in agent.bus.query(keys.recent_events(agent.site, role), timeout_s=5.0)]
        except BusError as exc:  # the bus closing under a stop: nothing to fetch, the agent goes on
            log.warning("could not fetch the agents' recent events: %s", exc)
            return
        for reply in replies:
            if not reply.ok:
                continue
            try:
                recent = RecentEvents.model_validate_json(reply.payload)
            except ValueError as exc:
                log.warning("ignoring the recent events on %s: %s", reply.key, exc)
                continue
            role = reply.key.rsplit("/", 2)[-2]
            for event in recent.events:
                self._queue(role, event, w.add_event)

    def _queue(self, role: str, msg, write: Callable) -> None:
        """Queue `msg`'s row if its source is an agent of `role`, the one role the router lets publish on its key."""
        if role_of_agent_id(msg.source) != role:
            self.tally["foreign"] += 1
            log.warning("not recording %s on a key only %r publishes: its source says %r",
                        type(msg).__name__, role, msg.source)  # fmt: skip
            return
        self._rows.put((write, msg))

    def _config(self, doc: ConfigDoc) -> None:
        problem = self._unsigned(doc)
        if problem:
            self.tally["refused_configs"] += 1
            log.warning("not recording config version %d: %s", doc.version, problem)
            return
        self._queue("configuration", doc, self.writer.add_config_change)

    def _write_loop(self, stopping: Callable[[], bool]) -> None:
        """Write the queued rows in arrival order until the agent stops (what is queued by then still goes in)."""
        while not (stopping() and self._rows.empty()):
            try:
                write, msg = self._rows.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                write(msg)
            except Exception:  # a row that does not go in must not stop the plant's control loop with it
                log.exception("could not record %s %s in history", type(msg).__name__, msg.id)
                self.tally["failed"] += 1
                continue
            self.tally["recorded"] += 1
