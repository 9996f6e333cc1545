"""History: plant states, applied actions, explanations, alerts, config changes and agent events in SQLite.

One file (``MeshSettings.history_file``) and one writer, the Sensor agent: it writes each step's
applied action, the next plant state and a checkpoint of the FMU state in one transaction (so a
restarted Sensor resumes with no gap in step indices), and records what the other agents publish
(``lcmesh.mesh.agents.recorder``): the Control agent's explanations, the Maintenance agent's alerts,
the Configuration agent's config documents, every agent's events. No other agent opens a
``HistoryWriter``, so a compromised agent cannot write a row the bus did not carry from the role
the router lets publish it.

Everyone else reads with ``HistoryReader``, a read-only (``mode=ro``) connection, which also works on
a read-only mount of the file's folder (docker-compose.yml): while the Sensor runs, its -wal and
-shm are there to read; when it has closed the file cleanly SQLite has removed them and a read-only
reader can not create them, so it reads the quiescent file as immutable.

The file and its -wal/-shm are created with mode 0600 (a missing parent folder with 0700) and
with incremental auto-vacuum, so the Sensor's writer can keep it under a bound
(``lcmesh.mesh.retention``, ``LCMESH_HISTORY__*``). ``HistoryReader`` is the read API the UI uses
(documented in docs/mesh.md).
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lcmesh.mesh.messages import AgentEvent, Alert, AppliedAction, ConfigDoc, Explanation, PlantState, utc_now
from lcmesh.mesh.retention import PassReport, Retention
from lcmesh.mesh.settings import HistoryConfig

log = logging.getLogger("lcmesh.mesh.history")
BLADE_BAND_K = (293.15, 313.15)
STATE_FIELDS = (
    "wet_bulb_k", "blade_temp_max_k", "blade_temp_mean_k", "blade_in_band_pct", "supply_temp_mean_k",
    "ct_leaving_temp_mean_k", "it_power_w", "it_cooling_w", "ct_fan_power_w", "pump_power_w", "heat_rejected_w",
)  # fmt: skip
_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY, system TEXT NOT NULL, system_hash TEXT NOT NULL, trace TEXT NOT NULL,
    started_at TEXT NOT NULL, ended_at TEXT);
CREATE TABLE IF NOT EXISTS plant_states (
    run_id TEXT NOT NULL, step INTEGER NOT NULL, time_s REAL NOT NULL, sent_at TEXT NOT NULL,
    {", ".join(f"{f} REAL" for f in STATE_FIELDS)}, faults_active INTEGER NOT NULL, payload TEXT,
    PRIMARY KEY (run_id, step));
CREATE TABLE IF NOT EXISTS actions (
    run_id TEXT NOT NULL, step INTEGER NOT NULL, time_s REAL NOT NULL, decision_id TEXT,
    source_controller TEXT NOT NULL, source_version TEXT NOT NULL, fallback INTEGER NOT NULL,
    fallback_reason TEXT, rejected_reason TEXT, n_clamps INTEGER NOT NULL, clamps TEXT NOT NULL,
    latency_ms REAL, late_ms REAL NOT NULL, applied_at TEXT NOT NULL, action TEXT NOT NULL,
    PRIMARY KEY (run_id, step));
CREATE TABLE IF NOT EXISTS checkpoints (
    run_id TEXT PRIMARY KEY, step INTEGER NOT NULL, fmu_state BLOB NOT NULL, sensor_state TEXT NOT NULL,
    saved_at TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS explanations (
    id INTEGER PRIMARY KEY AUTOINCREMENT, decision_id TEXT NOT NULL, step INTEGER NOT NULL,
    controller TEXT NOT NULL, level TEXT NOT NULL, text TEXT NOT NULL, facts TEXT NOT NULL,
    source TEXT NOT NULL, created_at TEXT NOT NULL, written_by TEXT NOT NULL DEFAULT 'renderer',
    why_renderer TEXT NOT NULL DEFAULT '', llm_part TEXT NOT NULL DEFAULT '');
CREATE INDEX IF NOT EXISTS explanations_decision ON explanations (decision_id);
CREATE TABLE IF NOT EXISTS alerts (
    id INTEGER PRIMARY KEY AUTOINCREMENT, alert_id TEXT NOT NULL, state TEXT NOT NULL, kind TEXT NOT NULL,
    severity TEXT NOT NULL, location TEXT NOT NULL, message TEXT NOT NULL, evidence TEXT NOT NULL,
    prescription TEXT NOT NULL, predicted_failure_s REAL, step INTEGER, time_s REAL, source TEXT NOT NULL,
    created_at TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS config_changes (
    version INTEGER PRIMARY KEY, changed_by TEXT NOT NULL, reason TEXT NOT NULL, changes TEXT NOT NULL,
    config TEXT NOT NULL, created_at TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS agent_events (
    id INTEGER PRIMARY KEY AUTOINCREMENT, kind TEXT NOT NULL, role TEXT NOT NULL, agent_id TEXT NOT NULL,
    detail TEXT NOT NULL, pid INTEGER, source TEXT NOT NULL, created_at TEXT NOT NULL);
"""


def _connect(path: Path, *, readonly: bool = False) -> sqlite3.Connection:
    if readonly:
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True, check_same_thread=False, timeout=10.0)
    else:
        _create_private(path)
        conn = sqlite3.connect(str(path), check_same_thread=False, timeout=10.0, isolation_level=None)
        conn.execute("PRAGMA auto_vacuum=INCREMENTAL")  # takes effect only in a file without tables: a new one
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=NORMAL")
    conn.execute("PRAGMA busy_timeout=10000")
    conn.row_factory = sqlite3.Row
    return conn


def _create_private(path: Path) -> None:
    """Create the file with mode 0600 (SQLite gives its -wal and -shm the same); tighten one left 0644 before."""
    if not path.exists():
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT, 0o600))
        return
    for p in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm")):
        if p.exists() and p.stat().st_mode & 0o077:
            os.chmod(p, 0o600)


def state_summary(msg: PlantState) -> dict[str, float | None]:
    """The summary columns of a plant state row."""
    out = msg.outputs

    def get(name: str, reduce) -> float | None:
        values = out.get(name)
        return float(reduce(np.asarray(values))) if values else None

    temps = np.asarray(out.get("blade_temp_k") or [np.nan])
    in_band = float(np.mean((temps > BLADE_BAND_K[0]) & (temps < BLADE_BAND_K[1])) * 100.0)
    return {
        "wet_bulb_k": msg.wet_bulb_k, "blade_temp_max_k": get("blade_temp_k", np.max),
        "blade_temp_mean_k": get("blade_temp_k", np.mean), "blade_in_band_pct": in_band,
        "supply_temp_mean_k": get("supply_temp_k", np.mean),
        "ct_leaving_temp_mean_k": get("ct_leaving_temp_k", np.mean),
        "it_power_w": get("it_power_w", np.sum), "it_cooling_w": get("it_cooling_w", np.sum),
        "ct_fan_power_w": get("ct_fan_power_w", np.sum), "pump_power_w": get("pump_power_w", np.sum),
        "heat_rejected_w": get("heat_rejected_w", np.sum),
    }  # fmt: skip


@dataclass(frozen=True)
class Checkpoint:
    run_id: str
    step: int
    fmu_state: bytes
    sensor_state: str  # JSON the Sensor needs besides the FMU state (last safe action, faults)


# columns added since the first schema: (table, column, declaration); a file written before them gets them on open
_ADDED_COLUMNS = (("explanations", "written_by", "TEXT NOT NULL DEFAULT 'renderer'"),
                  ("explanations", "why_renderer", "TEXT NOT NULL DEFAULT ''"),
                  ("explanations", "llm_part", "TEXT NOT NULL DEFAULT ''"))  # fmt: skip


def _add_missing_columns(conn) -> None:
    for table, column, decl in _ADDED_COLUMNS:
        if column not in {row[1] for row in conn.execute(f"PRAGMA table_info({table})")}:
            conn.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")
    conn.commit()


class HistoryWriter:
    """Writes history rows; safe to share between threads of one process.

    With `retention` (the Sensor's writer), ``maintain()`` keeps the file within it.
    """

    def __init__(self, path: str | Path, retention: HistoryConfig | None = None):
        self.path = Path(path)
        self._conn = _connect(self.path)
        self._lock = threading.Lock()
        self._retention = Retention(retention, self.path) if retention is not None else None
        with self._lock:
            self._conn.executescript(_SCHEMA)
            _add_missing_columns(self._conn)
            if self._retention is not None:
                self._retention.configure(self._conn)

    def close(self) -> None:
        with self._lock:
            self._conn.close()

    def _write(self, statements: Iterable[tuple[str, Sequence]]) -> None:
        with self._lock:
            self._conn.execute("BEGIN IMMEDIATE")
            try:
                for sql, params in statements:
                    self._conn.execute(sql, params)
                self._conn.execute("COMMIT")
            except BaseException:
                self._conn.execute("ROLLBACK")
                raise

    # --- runs and steps (the Sensor) ---------------------------------------------------------
    def start_run(self, run_id: str, system: str, system_hash: str, trace: str) -> None:
        self._write([("INSERT INTO runs VALUES (?, ?, ?, ?, ?, NULL)",
                      (run_id, system, system_hash, trace, utc_now().isoformat()))])  # fmt: skip

    def end_run(self, run_id: str) -> None:
        self._write([("UPDATE runs SET ended_at = ? WHERE run_id = ?", (utc_now().isoformat(), run_id))])

    def end_open_runs(self) -> int:
        """Mark every unfinished run finished (the next Sensor starts a new one); how many there were."""
        with self._lock:
            cursor = self._conn.execute("UPDATE runs SET ended_at = ? WHERE ended_at IS NULL", (utc_now().isoformat(),))
            return cursor.rowcount

    def resumable(self, system_hash: str, trace: str) -> Checkpoint | None:
        """The checkpoint of the newest unfinished run of this system and trace, if any."""
        with self._lock:
            row = self._conn.execute(
                "SELECT c.run_id, c.step, c.fmu_state, c.sensor_state FROM runs r JOIN checkpoints c USING (run_id) "
                "WHERE r.system_hash = ? AND r.trace = ? AND r.ended_at IS NULL ORDER BY r.started_at DESC LIMIT 1",
                (system_hash, trace),
            ).fetchone()
        return Checkpoint(row[0], row[1], bytes(row[2]), row[3]) if row else None

    def record_step(
        self, applied: AppliedAction | None, state: PlantState, *, payload: bool, checkpoint: tuple[bytes, str] | None
    ) -> None:
        """One transaction: the applied action of the last step, the new state, the FMU checkpoint."""
        statements = []
        if applied is not None:
            statements.append(_action_row(applied))
        statements.append(_state_row(state, payload))
        if checkpoint is not None:
            statements.append((
                "INSERT INTO checkpoints VALUES (?, ?, ?, ?, ?) ON CONFLICT(run_id) DO UPDATE SET "
                "step = excluded.step, fmu_state = excluded.fmu_state, sensor_state = excluded.sensor_state, "
                "saved_at = excluded.saved_at",
                (state.run_id, state.step, checkpoint[0], checkpoint[1], utc_now().isoformat()),
            ))  # fmt: skip
        self._write(statements)

    def maintain(self) -> PassReport | None:
        """Every ``prune_every_steps``-th call, one short retention pass (the Sensor calls it after each step).

        Retention is housekeeping: a failed pass is logged, not raised, the control loop goes on and the
        next pass retries.
        """
        if self._retention is None:
            return None
        try:
            return self._retention.tick(self._conn, self._lock)
        except Exception:
            log.exception("history retention pass failed; retried at the next one")
            return None

    # --- what the other agents publish (recorded by the Sensor, lcmesh.mesh.agents.recorder) ----------------
    def add_explanation(self, msg: Explanation) -> None:
        facts = json.dumps([f.model_dump() for f in msg.facts])
        self._write([("INSERT INTO explanations (decision_id, step, controller, level, text, facts, source, "
                      "created_at, written_by, why_renderer, llm_part) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                      (msg.decision_id, msg.step, msg.controller, msg.level, msg.text, facts, msg.source,
                       msg.sent_at.isoformat(), msg.written_by, msg.why_renderer, msg.llm_part))])  # fmt: skip

    def add_alert(self, msg: Alert) -> None:
        self._write([("INSERT INTO alerts (alert_id, state, kind, severity, location, message, evidence, "
                      "prescription, predicted_failure_s, step, time_s, source, created_at) "
                      "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                      (msg.alert_id, msg.state, msg.kind, msg.severity, msg.location, msg.message,
                       json.dumps(msg.evidence, default=str), msg.prescription, msg.predicted_failure_s, msg.step,
                       msg.time_s, msg.source, msg.sent_at.isoformat()))])  # fmt: skip

    def add_config_change(self, doc: ConfigDoc, changes: dict | None = None) -> None:
        """The audit row of a config version (`changes`: the doc's own); a version already audited is kept as is."""
        changes = doc.changes if changes is None else changes
        self._write([("INSERT OR IGNORE INTO config_changes VALUES (?, ?, ?, ?, ?, ?)",
                      (doc.version, doc.changed_by, doc.reason, json.dumps(changes, default=str),
                       doc.config.model_dump_json(), doc.sent_at.isoformat()))])  # fmt: skip

    def add_event(self, msg: AgentEvent) -> None:
        # once: an event comes live and again in its agent's recent events (fetched when the writer starts)
        self._write([("INSERT INTO agent_events (kind, role, agent_id, detail, pid, source, created_at) "
                      "SELECT ?, ?, ?, ?, ?, ?, ? WHERE NOT EXISTS (SELECT 1 FROM agent_events WHERE source = ? AND "
                      "created_at = ? AND kind = ? AND agent_id = ?)",
                      (msg.kind, msg.role, msg.agent_id, msg.detail, msg.pid, msg.source, msg.sent_at.isoformat(),
                       msg.source, msg.sent_at.isoformat(), msg.kind, msg.agent_id))])  # fmt: skip

    def reader(self) -> "HistoryReader":
        return HistoryReader(self.path)


def _state_row(state: PlantState, payload: bool) -> tuple[str, Sequence]:
    summary = state_summary(state)
    columns = ("run_id", "step", "time_s", "sent_at", *STATE_FIELDS, "faults_active", "payload")
    values = (state.run_id, state.step, state.time_s, state.sent_at.isoformat(), *(summary[f] for f in STATE_FIELDS),
              int(state.faults_active), state.model_dump_json() if payload else None)  # fmt: skip
    marks = ", ".join("?" * len(columns))
    return f"INSERT OR REPLACE INTO plant_states ({', '.join(columns)}) VALUES ({marks})", values


def _action_row(a: AppliedAction) -> tuple[str, Sequence]:
    clamps = json.dumps([c.model_dump() for c in a.clamps])
    return ("INSERT OR REPLACE INTO actions VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (a.run_id, a.step, a.time_s, a.decision_id, a.source_controller, a.source_version, int(a.fallback),
             a.fallback_reason, a.rejected_reason, len(a.clamps), clamps, a.latency_ms, a.late_ms,
             a.sent_at.isoformat(), a.action.model_dump_json()))  # fmt: skip


class HistoryReader:
    """Read-only queries over a history file (the UI's data source; every agent but the Sensor)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"history file not found: {self.path} (the Sensor creates it)")
        self._conn = _connect(self.path, readonly=True)
        self._lock = threading.Lock()

    def close(self) -> None:
        self._conn.close()

    def _rows(self, sql: str, params: Sequence = ()) -> list[dict]:
        with self._lock:
            try:
                return [dict(r) for r in self._conn.execute(sql, params).fetchall()]
            except sqlite3.OperationalError:
                if not self._writer_gone():
                    raise
            # the writer closed the file and took its -wal and -shm along; on a read-only mount no reader
            # can create them, so read the file as it is (nothing writes it until a writer opens it again)
            conn = sqlite3.connect(f"{self.path.resolve().as_uri()}?immutable=1", uri=True)
            conn.row_factory = sqlite3.Row
            try:
                return [dict(r) for r in conn.execute(sql, params).fetchall()]
            finally:
                conn.close()

    def _writer_gone(self) -> bool:
        """No -wal beside the file: no writer has it open, and every write is in the file itself."""
        return self.path.exists() and not self.path.with_name(self.path.name + "-wal").exists()

    def runs(self) -> list[dict]:
        """All runs, newest first."""
        return self._rows("SELECT * FROM runs ORDER BY started_at DESC")

    def latest_run_id(self) -> str | None:
        rows = self._rows("SELECT run_id FROM runs ORDER BY started_at DESC LIMIT 1")
        return rows[0]["run_id"] if rows else None

    def latest_state(self, run_id: str | None = None) -> PlantState | None:
        """The newest plant state with its full payload."""
        run_id = run_id or self.latest_run_id()
        rows = self._rows("SELECT payload FROM plant_states WHERE run_id = ? AND payload IS NOT NULL "
                          "ORDER BY step DESC LIMIT 1", (run_id,))  # fmt: skip
        return PlantState.model_validate_json(rows[0]["payload"]) if rows else None

    def state_at(self, step: int, run_id: str | None = None) -> PlantState | None:
        """The plant state of `step` with its full payload (None if not stored with one)."""
        run_id = run_id or self.latest_run_id()
        rows = self._rows("SELECT payload FROM plant_states WHERE run_id = ? AND step = ? AND payload IS NOT NULL",
                          (run_id, step))  # fmt: skip
        return PlantState.model_validate_json(rows[0]["payload"]) if rows else None

    def states(
        self, start_step: int = 0, end_step: int | None = None, fields: Sequence[str] = STATE_FIELDS,
        run_id: str | None = None, every: int = 1, limit: int = 10_000,
    ) -> list[dict]:  # fmt: skip
        """Summary rows (step, time_s and `fields`) of steps in [start_step, end_step], every `every`-th."""
        unknown = [f for f in fields if f not in STATE_FIELDS]
        if unknown:
            raise ValueError(f"unknown state field(s) {unknown}; known: {', '.join(STATE_FIELDS)}")
        if every < 1 or limit < 1:
            raise ValueError("`every` and `limit` must be >= 1")
        run_id = run_id or self.latest_run_id()
        end = end_step if end_step is not None else 2**62
        cols = ", ".join(("step", "time_s", *fields))
        return self._rows(f"SELECT {cols} FROM plant_states WHERE run_id = ? AND step BETWEEN ? AND ? "
                          "AND (step - ?) % ? = 0 ORDER BY step LIMIT ?",
                          (run_id, start_step, end, start_step, every, limit))  # fmt: skip

    def payload_states(
        self, start_step: int = 0, end_step: int | None = None, run_id: str | None = None, every: int = 1,
        limit: int = 500,
    ) -> list[PlantState]:  # fmt: skip
        """Plant states with their full payloads in [start_step, end_step], every `every`-th step, oldest first."""
        if every < 1 or limit < 1:
            raise ValueError("`every` and `limit` must be >= 1")
        run_id = run_id or self.latest_run_id()
        end = end_step if end_step is not None else 2**62
        rows = self._rows("SELECT payload FROM plant_states WHERE run_id = ? AND step BETWEEN ? AND ? AND payload IS "
                          "NOT NULL AND (step - ?) % ? = 0 ORDER BY step LIMIT ?",
                          (run_id, start_step, end, start_step, every, limit))  # fmt: skip
        return [PlantState.model_validate_json(r["payload"]) for r in rows]

    def decisions(self, limit: int = 50, since_step: int | None = None, run_id: str | None = None) -> list[dict]:
        """Applied actions newest first, with source, clamps, fallback and the explanation text if any."""
        run_id = run_id or self.latest_run_id()
        rows = self._rows(
            "SELECT a.*, e.text AS explanation, e.written_by AS explanation_written_by, e.why_renderer AS "
            "explanation_why_renderer, e.llm_part AS explanation_llm_part FROM actions a LEFT JOIN explanations e ON "
            "e.id = (SELECT MAX(id) FROM explanations WHERE decision_id = a.decision_id) WHERE a.run_id = ? AND "
            "a.step >= ? ORDER BY a.step DESC LIMIT ?", (run_id, since_step or 0, limit))  # fmt: skip
        for row in rows:
            row["clamps"] = json.loads(row["clamps"])
            row["action"] = json.loads(row["action"])
            row["fallback"] = bool(row["fallback"])
        return rows

    def explanations(self, decision_id: str | None = None, limit: int = 50) -> list[dict]:
        sql, params = "SELECT * FROM explanations", ()
        if decision_id is not None:
            sql, params = sql + " WHERE decision_id = ?", (decision_id,)
        rows = self._rows(sql + " ORDER BY id DESC LIMIT ?", (*params, limit))
        for row in rows:
            row["facts"] = json.loads(row["facts"])
        return rows

    def alerts(self, active_only: bool = False, limit: int = 100) -> list[dict]:
        """Alert rows newest first; `active_only`: the latest row of each alert id, if it is 'raised'."""
        if active_only:
            rows = self._rows("SELECT * FROM alerts WHERE id IN (SELECT MAX(id) FROM alerts GROUP BY alert_id) "
                              "AND state = 'raised' ORDER BY id DESC LIMIT ?", (limit,))  # fmt: skip
        else:
            rows = self._rows("SELECT * FROM alerts ORDER BY id DESC LIMIT ?", (limit,))
        for row in rows:
            row["evidence"] = json.loads(row["evidence"])
        return rows

    def config_changes(self, limit: int = 50) -> list[dict]:
        rows = self._rows("SELECT * FROM config_changes ORDER BY version DESC LIMIT ?", (limit,))
        for row in rows:
            row["changes"], row["config"] = json.loads(row["changes"]), json.loads(row["config"])
        return rows

    def agent_events(self, limit: int = 100, agent_id: str | None = None) -> list[dict]:
        if agent_id is None:
            return self._rows("SELECT * FROM agent_events ORDER BY id DESC LIMIT ?", (limit,))
        return self._rows("SELECT * FROM agent_events WHERE agent_id = ? ORDER BY id DESC LIMIT ?", (agent_id, limit))

    def first_step(self, table: str = "plant_states", run_id: str | None = None) -> int | None:
        """The oldest step of the run still in `table`: retention pruned the steps before it (None: no rows)."""
        _check_step_table(table)
        rows = self._rows(f"SELECT MIN(step) AS step FROM {table} WHERE run_id = ?", (run_id or self.latest_run_id(),))
        return rows[0]["step"]

    def step_gaps(self, table: str = "plant_states", run_id: str | None = None) -> list[tuple[int, int]]:
        """(after, before) pairs of missing step ranges in `table` ('plant_states' or 'actions').

        Among the rows retention kept: the pruned steps before ``first_step()`` are not a gap.
        """
        _check_step_table(table)
        run_id = run_id or self.latest_run_id()
        steps = [r["step"] for r in self._rows(f"SELECT step FROM {table} WHERE run_id = ? ORDER BY step", (run_id,))]
        return [(a, b) for a, b in zip(steps, steps[1:]) if b != a + 1]


def _check_step_table(table: str) -> None:
    if table not in ("plant_states", "actions"):
        raise ValueError(f"`table` must be 'plant_states' or 'actions', got {table!r}")
