"""History retention: a size bound and age limits, in tiers, so decisions and audit outlive raw states.

The Sensor's ``HistoryWriter`` runs a pass every ``prune_every_steps`` steps, after the step's
action is published, in its own connection. A pass is a few short transactions of at most
``batch_rows`` rows each (the step and the rows the Sensor records wait only that long), and starts no new
one after ``pass_budget_ms``; what is left waits for the next pass. Ages are wall-clock, measured
on each row's own timestamp (``sent_at``, ``applied_at``, ``created_at``), so they mean the same
at any speed factor and across runs; the size bound is what caps a fast demo.

| tier | rows | age limit (default) |
|---|---|---|
| payload | ``plant_states.payload`` set NULL, ``explanations.facts`` set ``[]`` | ``keep_payload_hours`` (24) |
| states | ``plant_states`` rows (the summary columns) | ``keep_states_hours`` (168) |
| decisions | ``actions`` and ``explanations`` rows | ``keep_decisions_hours`` (720) |
| audit | ``alerts``, ``agent_events``, ``config_changes`` but the newest | ``keep_audit_hours`` (2160) |

Over the size bound, a pass takes batches from the tier whose oldest row is oldest relative to its
age limit, so every tier keeps about the same share of its limit and the order of the limits holds:
decisions outlive states outlive payloads. Within a tier the oldest rows go first (rowid order,
which is write order), so what remains of a run is its newest steps. Never touched: an open run's newest
``keep_latest_steps`` steps (from the older of its newest state and its checkpoint) and every row
written after the oldest of them, and open runs' checkpoints; checkpoints of ended runs are dropped
(nothing resumes an ended run). Space returns to the file system through incremental auto-vacuum
(set when the file is created) and a ``wal_checkpoint(TRUNCATE)`` every ``TRUNCATE_EVERY_PASSES``.
"""

from __future__ import annotations

import logging
import sqlite3
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path

from lcmesh.mesh.messages import utc_now
from lcmesh.mesh.settings import HistoryConfig

log = logging.getLogger("lcmesh.mesh.retention")

BYTES_PER_MB = 1_000_000
MAX_WAL_BUDGET_BYTES = 8_000_000  # share of the bound left to the -wal file, at most this
FILL_FRACTION = 0.9  # pages in use are pruned to this share of the bound, less the -wal budget
VACUUM_FRACTION = 0.95  # free pages beyond this share (less the -wal budget) go back to the file system
TRUNCATE_EVERY_PASSES = 30
TRUNCATE_BUSY_MS = 20  # a checkpoint(TRUNCATE) waits this long for readers, else it is retried next time
VACUUM_PAGES_PER_PASS = 1024
TIERS = ("payload", "states", "decisions", "audit")

# partial indexes: the thinning tier finds the oldest rows that still carry detail without a scan
RETENTION_INDEXES = """
CREATE INDEX IF NOT EXISTS plant_states_payload_age ON plant_states (sent_at) WHERE payload IS NOT NULL;
CREATE INDEX IF NOT EXISTS explanations_facts_age ON explanations (created_at) WHERE facts != '[]';
"""


@dataclass
class PassReport:
    """What one retention pass did, and the file's size after it."""

    rows: dict[str, int] = field(default_factory=dict)  # per tier: rows thinned or deleted
    vacuumed_pages: int = 0
    truncated_wal: bool = False
    used_bytes: int = 0  # pages in use in the main file
    file_bytes: int = 0  # main file plus -wal on disk
    over_bound: bool = False  # still above the target when the pass ended (budget spent or nothing left to prune)
    elapsed_ms: float = 0.0


class Retention:
    """Applies a ``HistoryConfig`` to one writer connection; ``tick()`` once per Sensor step."""

    def __init__(self, cfg: HistoryConfig, path: Path):
        self.cfg, self.path = cfg, Path(path)
        self.max_bytes = int(cfg.max_mb * BYTES_PER_MB)
        self.wal_budget = min(self.max_bytes // 8, MAX_WAL_BUDGET_BYTES) if self.max_bytes else MAX_WAL_BUDGET_BYTES
        self.target_bytes = int(self.max_bytes * FILL_FRACTION) - self.wal_budget if self.max_bytes else 0
        self.file_allowance = int(self.max_bytes * VACUUM_FRACTION) - self.wal_budget if self.max_bytes else 0
        self.limits_h = (cfg.keep_payload_hours, cfg.keep_states_hours, cfg.keep_decisions_hours, cfg.keep_audit_hours)
        self._vacuum_pages = VACUUM_PAGES_PER_PASS  # at most half the -wal budget: the moved pages pass through it
        self._calls = 0
        self._passes = 0
        self._window_ms: list[float] = []
        self._window_rows = dict.fromkeys(TIERS, 0)

    def configure(self, conn: sqlite3.Connection) -> None:
        """WAL limits on the pruning connection; warn once if the file can not shrink."""
        page_size = conn.execute("PRAGMA page_size").fetchone()[0]
        self._vacuum_pages = max(16, min(VACUUM_PAGES_PER_PASS, self.wal_budget // 2 // page_size))
        conn.execute(f"PRAGMA wal_autocheckpoint={max(16, self.wal_budget // 2 // page_size)}")
        conn.execute(f"PRAGMA journal_size_limit={self.wal_budget // 2}")
        conn.executescript(RETENTION_INDEXES)
        if conn.execute("PRAGMA auto_vacuum").fetchone()[0] != 2:
            log.warning("%s was created without incremental auto-vacuum: pruning stops its growth but it will not "
                        "shrink; run `sqlite3 %s 'PRAGMA auto_vacuum=INCREMENTAL; VACUUM'` once with the mesh "
                        "stopped", self.path, self.path)  # fmt: skip

    def tick(self, conn: sqlite3.Connection, lock: threading.Lock) -> PassReport | None:
        """Every ``prune_every_steps``-th call, one pass; else None."""
        self._calls += 1
        if self._calls % self.cfg.prune_every_steps:
            return None
        return self.run_pass(conn, lock)

    def run_pass(self, conn: sqlite3.Connection, lock: threading.Lock) -> PassReport:
        """Age limits, then the size bound, then vacuum and (now and then) a WAL truncation."""
        start = time.perf_counter()
        deadline = start + self.cfg.pass_budget_ms / 1e3
        report = PassReport(rows=dict.fromkeys(TIERS, 0))
        with lock:
            protect_since = _protected_since(conn, self.cfg.keep_latest_steps) or utc_now().isoformat()
            if conn.execute(f"SELECT 1 FROM checkpoints WHERE {_ENDED_RUN} LIMIT 1").fetchone():
                _write(conn, f"DELETE FROM checkpoints WHERE {_ENDED_RUN}")
        now = utc_now()
        for tier, hours in zip(TIERS, self.limits_h):
            if hours and time.perf_counter() < deadline:
                cutoff = min((now - timedelta(hours=hours)).isoformat(), protect_since)
                with lock:  # a read first: most passes have nothing to age out, and take no write lock
                    stamp = _oldest_stamp(conn, tier)
                    if stamp is not None and stamp < cutoff:
                        report.rows[tier] += _PRUNE[tier](conn, cutoff, self.cfg.batch_rows)
        while self.max_bytes and time.perf_counter() < deadline:
            with lock:
                if _used_bytes(conn) <= self.target_bytes:
                    break
                tier = self._most_overdue(conn, protect_since)
                done = _PRUNE[tier](conn, protect_since, self.cfg.batch_rows) if tier else 0
            if not done:  # only protected rows are left: keep_latest_steps does not fit in the bound
                break
            report.rows[tier] += done
        with lock:
            report.vacuumed_pages = self._vacuum(conn)
            self._passes += 1
            if self._passes % TRUNCATE_EVERY_PASSES == 0:
                report.truncated_wal = _truncate_wal(conn)
            report.used_bytes = _used_bytes(conn)
        report.over_bound = bool(self.max_bytes) and report.used_bytes > self.target_bytes
        report.file_bytes = file_bytes(self.path)
        report.elapsed_ms = (time.perf_counter() - start) * 1e3
        log.debug("retention pass: %s", report)
        self._summarize(report)
        return report

    def _summarize(self, report: PassReport) -> None:
        """An INFO line every ``TRUNCATE_EVERY_PASSES`` passes: size, bound, rows pruned, slowest pass."""
        self._window_ms.append(report.elapsed_ms)
        for tier, n in report.rows.items():
            self._window_rows[tier] += n
        if len(self._window_ms) < TRUNCATE_EVERY_PASSES:
            return
        ms = sorted(self._window_ms)
        bound = f"{self.max_bytes / BYTES_PER_MB:g} MB" if self.max_bytes else "none"
        rows = ", ".join(f"{tier} {n}" for tier, n in self._window_rows.items())
        log.info("history %.1f MB on disk (bound %s); last %d passes: %s rows thinned/deleted, pass ms median "
                 "%.1f max %.1f", report.file_bytes / BYTES_PER_MB, bound, len(ms), rows, ms[len(ms) // 2],
                 ms[-1])  # fmt: skip
        self._window_ms, self._window_rows = [], dict.fromkeys(TIERS, 0)

    def _most_overdue(self, conn: sqlite3.Connection, protect_since: str) -> str | None:
        """The tier whose oldest prunable row is oldest for its age limit; tiers without a limit after those with one.

        So under the size bound every tier keeps about the same share of its age limit, and decisions
        (720 h by default) outlive states (168 h) outlive full payloads (24 h).
        """
        now, best, best_key = utc_now(), None, None
        for index, (tier, hours) in enumerate(zip(TIERS, self.limits_h)):
            stamp = _oldest_stamp(conn, tier)
            if stamp is None or stamp >= protect_since:
                continue
            age_s = (now - datetime.fromisoformat(stamp)).total_seconds()
            key = (1, age_s / (hours * 3600), -index) if hours else (0, -index, age_s)
            if best_key is None or key > best_key:
                best, best_key = tier, key
        return best

    def _vacuum(self, conn: sqlite3.Connection) -> int:
        """Free pages back to the file system above the file's allowance; below it, new rows reuse them.

        (Vacuuming every freed page would move live pages from the end of the file at each pass.)
        """
        page_size, pages, free = (conn.execute(f"PRAGMA {p}").fetchone()[0]
                                  for p in ("page_size", "page_count", "freelist_count"))  # fmt: skip
        excess = pages - self.file_allowance // page_size if self.max_bytes else free - pages // 10
        n = min(free, excess, self._vacuum_pages)
        if n <= 0:
            return 0
        # executescript steps the pragma to its end (execute() frees one page per step, so only one)
        conn.executescript(f"PRAGMA incremental_vacuum({n});")
        return free - conn.execute("PRAGMA freelist_count").fetchone()[0]


def file_bytes(path: Path) -> int:
    """The history file plus its -wal on disk."""
    total = 0
    for p in (path, path.with_name(path.name + "-wal")):
        try:
            total += p.stat().st_size
        except FileNotFoundError:
            pass
    return total


def _used_bytes(conn: sqlite3.Connection) -> int:
    page_size, pages, free = (conn.execute(f"PRAGMA {p}").fetchone()[0]
                              for p in ("page_size", "page_count", "freelist_count"))  # fmt: skip
    return (pages - free) * page_size


def _protected_since(conn: sqlite3.Connection, keep_latest_steps: int) -> str | None:
    """``sent_at`` of the oldest protected state over the open runs (rows this old or newer are kept)."""
    oldest = None
    for run_id, newest, ckpt in conn.execute(
        "SELECT r.run_id, (SELECT MAX(step) FROM plant_states s WHERE s.run_id = r.run_id), "
        "(SELECT step FROM checkpoints c WHERE c.run_id = r.run_id) FROM runs r WHERE r.ended_at IS NULL"
    ).fetchall():
        if newest is None:
            continue
        floor = min(newest, ckpt if ckpt is not None else newest) - keep_latest_steps + 1
        row = conn.execute("SELECT sent_at FROM plant_states WHERE run_id = ? AND step >= ? ORDER BY step LIMIT 1",
                           (run_id, floor)).fetchone()  # fmt: skip
        if row is not None and (oldest is None or row[0] < oldest):
            oldest = row[0]
    return oldest


_ENDED_RUN = "run_id IN (SELECT run_id FROM runs WHERE ended_at IS NOT NULL)"
_OLDEST = {  # per tier, queries whose first column is the stamp of the row `_PRUNE` would take first
    "payload": ("SELECT MIN(sent_at) FROM plant_states WHERE payload IS NOT NULL",
                "SELECT MIN(created_at) FROM explanations WHERE facts != '[]'"),
    "states": ("SELECT sent_at FROM plant_states ORDER BY rowid LIMIT 1",),
    "decisions": ("SELECT applied_at FROM actions ORDER BY rowid LIMIT 1",
                  "SELECT created_at FROM explanations ORDER BY id LIMIT 1"),
    "audit": ("SELECT created_at FROM alerts ORDER BY id LIMIT 1",
              "SELECT created_at FROM agent_events ORDER BY id LIMIT 1",
              "SELECT MIN(created_at) FROM config_changes WHERE version < (SELECT MAX(version) FROM config_changes)"),
}  # fmt: skip


def _oldest_stamp(conn: sqlite3.Connection, tier: str) -> str | None:
    stamps = [row[0] for sql in _OLDEST[tier] for row in conn.execute(sql).fetchall() if row[0] is not None]
    return min(stamps) if stamps else None


def _write(conn: sqlite3.Connection, sql: str, params: tuple = ()) -> tuple[int, list]:
    """One short write transaction: (rows changed, rows a RETURNING clause gave)."""
    conn.execute("BEGIN IMMEDIATE")
    try:
        cursor = conn.execute(sql, params)
        returned = cursor.fetchall()
        conn.execute("COMMIT")
    except BaseException:
        conn.execute("ROLLBACK")
        raise
    return max(cursor.rowcount, len(returned)), returned


def _oldest(table: str, key: str, stamp: str) -> str:
    """Rows among the `limit` oldest (write order) of `table` stamped before the cutoff."""
    return f"SELECT {key} FROM (SELECT {key}, {stamp} FROM {table} ORDER BY {key} LIMIT ?) WHERE {stamp} < ?"


def _thin(conn: sqlite3.Connection, cutoff: str, n: int) -> int:
    """Drop the full state JSON and explanation facts of the oldest rows (summary and text stay)."""
    states, _ = _write(conn, "UPDATE plant_states SET payload = NULL WHERE rowid IN (SELECT rowid FROM plant_states "
                       "WHERE payload IS NOT NULL AND sent_at < ? ORDER BY sent_at LIMIT ?)", (cutoff, n))  # fmt: skip
    facts, _ = _write(conn, "UPDATE explanations SET facts = '[]' WHERE id IN (SELECT id FROM explanations "
                      "WHERE facts != '[]' AND created_at < ? ORDER BY created_at LIMIT ?)", (cutoff, n))  # fmt: skip
    return states + facts


def _drop_states(conn: sqlite3.Connection, cutoff: str, n: int) -> int:
    sql = f"DELETE FROM plant_states WHERE rowid IN ({_oldest('plant_states', 'rowid', 'sent_at')})"
    return _write(conn, sql, (n, cutoff))[0]


def _drop_decisions(conn: sqlite3.Connection, cutoff: str, n: int) -> int:
    """The oldest actions, and the explanations written before the newest of them (or before `cutoff`)."""
    oldest_actions = _oldest("actions", "rowid", "applied_at")
    oldest_explanations = _oldest("explanations", "id", "created_at")
    n_applied, applied = _write(conn, f"DELETE FROM actions WHERE rowid IN ({oldest_actions}) RETURNING applied_at",
                                (n, cutoff))  # fmt: skip
    explained_before = max(r[0] for r in applied) if applied else cutoff
    n_explained, _ = _write(conn, f"DELETE FROM explanations WHERE id IN ({oldest_explanations})",
                            (n, explained_before))  # fmt: skip
    return n_applied + n_explained


def _drop_audit(conn: sqlite3.Connection, cutoff: str, n: int) -> int:
    """The oldest alerts and agent events; config changes but the newest (the Configuration agent checks it)."""
    done = 0
    for table in ("alerts", "agent_events"):
        done += _write(conn, f"DELETE FROM {table} WHERE id IN ({_oldest(table, 'id', 'created_at')})", (n, cutoff))[0]
    done += _write(conn, "DELETE FROM config_changes WHERE version IN (SELECT version FROM config_changes "
                   "WHERE created_at < ? AND version < (SELECT MAX(version) FROM config_changes) "
                   "ORDER BY version LIMIT ?)", (cutoff, n))[0]  # fmt: skip
    return done


def _truncate_wal(conn: sqlite3.Connection) -> bool:
    """checkpoint(TRUNCATE) with a short busy wait, so a reader in the way costs a retry, not a stalled step."""
    conn.execute(f"PRAGMA busy_timeout={TRUNCATE_BUSY_MS}")
    try:
        busy = conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()[0]
    finally:
        conn.execute("PRAGMA busy_timeout=10000")
    return busy == 0


_PRUNE = {"payload": _thin, "states": _drop_states, "decisions": _drop_decisions, "audit": _drop_audit}
