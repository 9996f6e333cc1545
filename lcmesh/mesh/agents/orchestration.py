"""The Orchestration agent: starts the other agents, sees them die, restarts them with backoff.

Death is seen three ways: the child process exits (polled every 50 ms), its liveliness token
goes and does not come back within ``hung_after_s`` (the router drops a session at once when its
socket closes, or after the lease when the process hangs, e.g. SIGSTOP), or it stays alive but
stops publishing stats for ``hung_after_s``. The last two count only while this agent's own
session reaches a router, and from ``RECONNECT_GRACE_S`` after it got it back from an outage:
when the router dies every token goes at once and no stats flow, yet the agents are healthy and
reconnect by themselves. A dead or hung agent is SIGKILLed (its whole process group), reported as an
event with the tail of its log, and restarted after a backoff that doubles on repeated deaths
and resets once it has run for ``healthy_after_s``. A role whose module does not import yet
(the UI before its issue lands) is skipped with a clear log line and a ``skipped`` event.

It acts only on processes it started itself or adopted from its predecessor's pid files, each
checked by pid and start time (a recycled pid is not the agent), never on a pid a bus message
names: a stats message with another pid for a supervised agent id is counted and reported, not
acted on. Whose stats or token it is comes from the key (the router lets role R publish only on
``monitor/stats/R*`` and ``alive/R/*``), never from the message: stats for the Sensor sent by another
role are dropped and counted (``Agent.subscribe_stats``), so they can not keep a hung Sensor "alive".
Its agents are tied to it (``processes.tie_to_parent``): when it dies, however it dies, they get
SIGTERM and stop within ``processes.ORPHAN_STOP_GRACE_S`` (those it stops itself: all at once,
SIGKILLed after ``stop_timeout_s``), so a killed orchestrator leaves no orphan and its successor
starts them afresh (the Sensor resumes its run from the checkpoint). One that outlived it all the
same (stopped, or still on its way out) is adopted from its predecessor's pid files and the tokens
a liveliness query finds, never duplicated. With ``supervise = false`` (docker compose, where the
container engine restarts) it only watches and reports.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
from dataclasses import dataclass

from lcmesh.mesh import keys
from lcmesh.mesh.agents.base import Agent
from lcmesh.mesh.agents.registry import check_role, unavailable_reason
from lcmesh.mesh.messages import AgentStats, CommandReply
from lcmesh.mesh.processes import (
    Child, agent_child, agent_env, read_pidfile, same_process, start_ticks, stop_children,
)  # fmt: skip

log = logging.getLogger("lcmesh.mesh.agents.orchestration")
START_GRACE_S = 20.0  # a started agent must declare its token within this, or it is restarted
RECONNECT_GRACE_S = 10.0  # after (re)gaining the router, agents get this long to reconnect before being judged


@dataclass
class Managed:
    """One supervised agent: ``down`` -> (start) -> ``starting`` -> (token) -> ``up`` -> (death) -> ``down``."""

    role: str
    agent_id: str
    state: str = "down"
    child: Child | None = None
    adopted_pid: int | None = None
    up_since: float | None = None
    down_since: float | None = None
    started_at: float = 0.0
    next_start_at: float = 0.0
    backoff_s: float = 0.0
    starts: int = 0
    last_stats_at: float | None = None
    token_lost_at: float | None = None
    adopted_start: int | None = None

    @property
    def alive(self) -> bool:
        return self.state == "up"

    @property
    def pid(self) -> int | None:
        """The process this orchestrator started or adopted, if it still runs (never a pid from a message)."""
        if self.child is not None and self.child.running():
            return self.child.pid
        if self.adopted_pid is not None and same_process(self.adopted_pid, self.adopted_start):
            return self.adopted_pid
        return None


class OrchestrationAgent(Agent):
    role = "orchestration"

    def __init__(self, settings, agent_id: str | None = None):
        super().__init__(settings, agent_id)
        self.cfg = settings.orchestration
        self.managed: dict[str, Managed] = {}
        self.skipped: dict[str, str] = {}
        self._lock = threading.RLock()
        self._env = {**os.environ, **settings.to_env()}  # each child gets it less what its role must not see
        self._adopting_done = False
        self._host = socket.gethostname()
        self._connected_since: float | None = None
        self.tally = {"foreign_stats": 0, "router_outages": 0}

    # --- lifecycle ------------------------------------------------------------------------------
    def on_start(self) -> None:
        for role in self.cfg.roles:
            check_role(role)
            if role == self.role:
                continue
            reason = unavailable_reason(role)
            if reason is not None:
                self.skipped[role] = reason
                log.warning("skipping role %r: %s", role, reason)
                self.emit_event("skipped", reason, role=role, agent_id=role)
                continue
            self.managed[role] = Managed(role=role, agent_id=role)
        self.watch_agents(self._on_liveliness)
        self.subscribe_stats(self._on_stats)
        self.serve(keys.cmd(self.site, self.agent_id, "status"), self._status)
        self.spawn("supervise", self._supervise)

    def on_stop(self) -> None:
        """Stop every supervised agent: all asked at once, all given the same `stop_timeout_s`, then killed."""
        if not self.cfg.supervise:
            return
        with self._lock:
            agents = list(reversed(list(self.managed.values())))
            stop_children([m.child for m in agents if m.child is not None and m.child.popen is not None],
                          self.cfg.stop_timeout_s)  # fmt: skip
            for m in agents:
                self._terminate(m, graceful=True)  # adopted ones, and the pid files

    def details(self) -> dict:
        with self._lock:
            return {"agents": {m.agent_id: {"role": m.role, "state": m.state, "pid": m.pid, "starts": m.starts}
                               for m in self.managed.values()}, "skipped": self.skipped, **self.tally}  # fmt: skip

    def _status(self, _payload: bytes | None) -> CommandReply:
        return CommandReply(ok=True, data=self.details())

    # --- what the bus tells -------------------------------------------------------------------------
    def _on_liveliness(self, role: str, agent_id: str, alive: bool) -> None:
        with self._lock:
            m = self.managed.get(agent_id)
            if m is None or m.role != role:
                return
            now = time.monotonic()
            if alive:
                m.token_lost_at = None
            if alive and m.state != "up":
                m.state, m.up_since = "up", now
                if m.down_since is not None:
                    self.emit_event("restarted", f"back after {now - m.down_since:.2f} s (start {m.starts})",
                                    role=m.role, agent_id=m.agent_id, pid=m.pid)  # fmt: skip
                elif self._adopting_done:
                    self.emit_event("started", f"up {now - m.started_at:.2f} s after start", role=m.role,
                                    agent_id=m.agent_id, pid=m.pid)  # fmt: skip
                m.down_since = None
            elif not alive and m.state == "up" and m.token_lost_at is None:
                m.token_lost_at = now  # judged in _check: the router may be gone, not the agent

    def _on_stats(self, stats: AgentStats) -> None:
        """Stats keep a supervised agent from counting as hung; their pid is a claim, never acted on."""
        with self._lock:
            m = self.managed.get(stats.agent_id)
            if m is None or m.role != stats.role:
                return
            ours = m.pid
            if ours is not None and stats.host == self._host and stats.pid != ours:
                self.tally["foreign_stats"] += 1
                if self.tally["foreign_stats"] in (1, 10, 100) or self.tally["foreign_stats"] % 1000 == 0:
                    self.emit_event("warning", f"stats for {m.agent_id} name pid {stats.pid}, but the supervised "
                                    f"process is {ours}; not acting on a pid from a message "
                                    f"({self.tally['foreign_stats']} so far)", role=m.role, agent_id=m.agent_id)
                return
            m.last_stats_at = time.monotonic()

    # --- supervision ----------------------------------------------------------------------------------
    def _supervise(self) -> None:
        self._adopt()
        while not self.wait(0.05):
            with self._lock:
                now = time.monotonic()
                judging = self._judging_silence(now)
                for m in self.managed.values():
                    self._check(m, now, judging)

    def _judging_silence(self, now: float) -> bool:
        """Whether a lost token or missing stats may be blamed on an agent: our own link has been up for a while."""
        if not self.bus.connected():
            if self._connected_since is not None:
                self.tally["router_outages"] += 1
                log.warning("no router reachable; not judging agents by tokens or stats until it is back")
            self._connected_since = None
            return False
        if self._connected_since is None:
            self._connected_since = now
            for m in self.managed.values():  # stats and tokens resume after the reconnection
                if m.last_stats_at is not None:
                    m.last_stats_at = max(m.last_stats_at, now)
        grace = max(self.cfg.hung_after_s, RECONNECT_GRACE_S) if self.tally["router_outages"] else 0.0
        return now - self._connected_since >= grace

    def _adopt(self) -> None:
        """Take over agents a previous orchestrator left running (its pid files, live tokens), never duplicate them."""
        try:
            tokens = set(self.bus.alive(keys.alive_all(self.site), timeout_s=2.0))
        except Exception as exc:  # no answer: pid files alone decide
            log.warning("liveliness query failed (%s); adopting from pid files only", exc)
            tokens = set()
        now = time.monotonic()
        with self._lock:
            for m in self.managed.values():
                pid, start = self._read_pidfile(m)
                token = keys.alive(self.site, m.role, m.agent_id) in tokens
                if pid is None and not token:
                    continue
                m.adopted_pid, m.adopted_start = pid, start
                if m.state != "up":
                    m.state = "up" if token else "starting"
                    m.started_at, m.up_since = now, now if token else None
                self.emit_event("adopted", f"already running as pid {m.adopted_pid}", role=m.role,
                                agent_id=m.agent_id, pid=m.adopted_pid)  # fmt: skip
            self._adopting_done = True

    def _check(self, m: Managed, now: float, judging: bool = True) -> None:
        child_exited = m.child is not None and m.child.popen is not None and not m.child.running()
        adopted_gone = (m.child is None and m.adopted_pid is not None
                        and not same_process(m.adopted_pid, m.adopted_start))  # fmt: skip
        if m.state == "up":
            if child_exited:
                self._died(m, f"process exited with code {m.child.popen.returncode}")
            elif adopted_gone:
                self._died(m, f"adopted process {m.adopted_pid} is gone")
            elif not judging:
                return
            elif m.token_lost_at is not None and now - m.token_lost_at > self.cfg.hung_after_s:
                self._died(m, f"liveliness token lost {now - m.token_lost_at:.1f} s ago while the router is "
                           "reachable (hung or disconnected)", kind="hung")  # fmt: skip
            elif m.last_stats_at is not None and now - m.last_stats_at > self.cfg.hung_after_s:
                self._died(m, f"alive but silent for {now - m.last_stats_at:.1f} s (hung)", kind="hung")
        elif m.state == "starting":
            if child_exited:
                self._died(m, f"process exited with code {m.child.popen.returncode} while starting")
            elif adopted_gone:
                self._died(m, f"adopted process {m.adopted_pid} exited while starting")
            elif judging and now - m.started_at > START_GRACE_S:
                self._died(m, f"no liveliness token {START_GRACE_S:.0f} s after start", kind="hung")
        elif self.cfg.supervise and now >= m.next_start_at and not self.stopping:  # none after on_stop's snapshot
            self._start(m, now)

    def _died(self, m: Managed, reason: str, kind: str = "died") -> None:
        now = time.monotonic()
        pid = m.pid
        tail = m.child.log_tail(12) if m.child is not None else ""
        if self.cfg.supervise:
            self._terminate(m, graceful=False)
        healthy = m.up_since is not None and now - m.up_since > self.cfg.healthy_after_s
        if healthy or m.backoff_s == 0:
            m.backoff_s = self.cfg.backoff_initial_s
        else:
            m.backoff_s = min(self.cfg.backoff_max_s, 2 * m.backoff_s)
        m.state, m.last_stats_at, m.up_since, m.token_lost_at = "down", None, None, None
        m.down_since = m.down_since if m.down_since is not None else now
        m.next_start_at = now + m.backoff_s
        detail = f"{reason}; restarting in {m.backoff_s:.1f} s" if self.cfg.supervise else reason
        log.warning("%s %s: %s", m.role, m.agent_id, detail)
        self.emit_event(kind, detail + (f"\nlast log lines:\n{tail}" if tail else ""), role=m.role,
                        agent_id=m.agent_id, pid=pid)  # fmt: skip

    def _start(self, m: Managed, now: float) -> None:
        log_path = self.settings.log_dir / f"{m.agent_id}.log"
        m.child = agent_child(m.role, m.agent_id, self.child_env(m.role), log_path).start()
        m.adopted_pid, m.adopted_start, m.started_at, m.state = None, None, now, "starting"
        m.starts += 1
        log.info("started %s as pid %d (log %s)", m.agent_id, m.child.pid, log_path)
        self._write_pidfile(m)

    def child_env(self, role: str) -> dict[str, str]:
        """The environment an agent of `role` starts with: no secret but its own role's (``processes.agent_env``)."""
        return agent_env(self._env, role, self.settings.secrets_path)

    def _terminate(self, m: Managed, graceful: bool) -> None:
        if m.child is not None and m.child.popen is not None:
            if graceful:
                m.child.stop(self.cfg.stop_timeout_s)
            else:
                m.child.signal(signal.SIGKILL)
                try:
                    m.child.popen.wait(timeout=2.0)
                except Exception:
                    pass
        if m.adopted_pid is not None and same_process(m.adopted_pid, m.adopted_start):
            _kill_adopted(m.adopted_pid, graceful, self.cfg.stop_timeout_s)
        m.adopted_pid = m.adopted_start = None
        self._remove_pidfile(m)

    def _write_pidfile(self, m: Managed) -> None:
        path = self.settings.data_dir / "pids" / f"{m.agent_id}.pid"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"{m.child.pid} {start_ticks(m.child.pid)}")

    def _remove_pidfile(self, m: Managed) -> None:
        (self.settings.data_dir / "pids" / f"{m.agent_id}.pid").unlink(missing_ok=True)

    def _read_pidfile(self, m: Managed) -> tuple[int | None, int | None]:
        """(pid, start time) a previous orchestrator wrote for `m`, if that very process still runs as an agent."""
        found = read_pidfile(self.settings.data_dir / "pids" / f"{m.agent_id}.pid")
        if found is None:
            return None, None
        pid, start = found
        return (pid, start) if same_process(pid, start) and _is_agent_process(pid) else (None, None)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a zombie (exited, not yet reaped by its dead parent) counts as gone
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _is_agent_process(pid: int) -> bool:
    try:
        return b"lcmesh.mesh.agents" in open(f"/proc/{pid}/cmdline", "rb").read()
    except OSError:
        return False


def _kill_adopted(pid: int, graceful: bool, timeout_s: float) -> None:
    for sig in ((signal.SIGCONT, signal.SIGTERM) if graceful else ()) + (signal.SIGKILL,):
        try:
            os.killpg(pid, sig) if os.getpgid(pid) == pid else os.kill(pid, sig)
        except (ProcessLookupError, PermissionError):
            return
        if sig == signal.SIGTERM:
            deadline = time.monotonic() + timeout_s
            while _pid_alive(pid) and time.monotonic() < deadline:
                time.sleep(0.05)
            if not _pid_alive(pid):
                return
