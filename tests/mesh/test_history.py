"""History in a real SQLite file: one transaction per step, resume checkpoints, the reader API."""

from __future__ import annotations

import os
import shutil
import sqlite3
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from lcmesh.mesh.history import STATE_FIELDS, HistoryReader, HistoryWriter
from lcmesh.mesh.messages import ActionModel, AgentEvent, Alert, AppliedAction, ConfigDoc, MeshConfig, plant_state_from_outputs


def _state(plant, system, step, run_id="run1"):
    return plant_state_from_outputs(plant.out, source="sensor", system=system, run_id=run_id, step=step,
                                    time_s=15.0 * step, wet_bulb_k=290.0, blade_power_w=[1e4] * system.n_blade_groups,
                                    period_s=0.25)  # fmt: skip


def _applied(plant, step, run_id="run1", fallback=False):
    return AppliedAction(source="sensor", run_id=run_id, step=step, time_s=15.0 * step, decision_id=f"d{step}",
                         source_controller="g36", source_version="1", action=ActionModel.from_action(plant.default_action()),
                         fallback=fallback, fallback_reason="no proposal" if fallback else None, latency_ms=1.5)  # fmt: skip


def test_steps_checkpoints_and_the_reader(tmp_path, plant, lcopt5):
    w = HistoryWriter(tmp_path / "h.sqlite")
    w.start_run("run1", lcopt5.name, lcopt5.content_hash(), "trace-x")
    w.record_step(None, _state(plant, lcopt5, 0), payload=True, checkpoint=(b"fmu0", '{"action": {}}'))
    for k in range(3):
        w.record_step(_applied(plant, k, fallback=k == 1), _state(plant, lcopt5, k + 1), payload=k % 2 == 0,
                      checkpoint=(f"fmu{k + 1}".encode(), "{}"))  # fmt: skip
    ckpt = w.resumable(lcopt5.content_hash(), "trace-x")
    assert ckpt.run_id == "run1" and ckpt.step == 3 and ckpt.fmu_state == b"fmu3"
    assert w.resumable(lcopt5.content_hash(), "other-trace") is None
    r = HistoryReader(tmp_path / "h.sqlite")
    assert r.latest_run_id() == "run1" and r.step_gaps() == [] and r.step_gaps("actions") == []
    rows = r.states(fields=("blade_temp_max_k", "it_power_w"))
    assert [row["step"] for row in rows] == [0, 1, 2, 3] and set(rows[0]) == {"step", "time_s", "blade_temp_max_k", "it_power_w"}
    assert rows[1]["blade_temp_max_k"] == pytest.approx(float(plant.out["blade_temp_k"].max()))
    assert [row["step"] for row in r.states(start_step=1, every=2)] == [1, 3]
    assert r.latest_state().step == 3 and r.latest_state().outputs.keys() == plant.out.keys()
    decisions = r.decisions()
    assert [d["step"] for d in decisions] == [2, 1, 0] and decisions[1]["fallback"] is True
    with pytest.raises(ValueError, match="unknown state field"):
        r.states(fields=("blade_temp",))
    assert w.end_open_runs() == 1
    assert w.resumable(lcopt5.content_hash(), "trace-x") is None, "a finished run is not resumed"
    assert r.runs()[0]["ended_at"] is not None
    assert set(STATE_FIELDS) <= {c[1] for c in sqlite3.connect(tmp_path / "h.sqlite").execute("PRAGMA table_info(plant_states)")}


def test_alerts_events_config_and_concurrent_writers(tmp_path):
    path = tmp_path / "h.sqlite"
    writers = [HistoryWriter(path) for _ in range(3)]

    def write(w, n):
        for i in range(40):
            w.add_event(AgentEvent(source="o", kind="started", role="sensor", agent_id=f"a{n}", detail=str(i)))

    threads = [threading.Thread(target=write, args=(w, n)) for n, w in enumerate(writers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    w = writers[0]
    raised = Alert(source="m", alert_id="al1", state="raised", kind="pump_degradation", location="cabinet_2")
    w.add_alert(raised)
    w.add_alert(Alert(source="m", alert_id="al2", state="raised", kind="cell_out", location="tower_0/cell_1"))
    w.add_alert(raised.model_copy(update={"state": "cleared"}))
    w.add_config_change(ConfigDoc(source="c", version=2, config=MeshConfig(), changed_by="op"), {"speed_factor": [60, 120]})
    r = HistoryReader(path)
    assert len(r.agent_events(limit=1000)) == 120 and len(r.agent_events(agent_id="a1", limit=1000)) == 40
    assert [a["alert_id"] for a in r.alerts(active_only=True)] == ["al2"]
    assert len(r.alerts()) == 3
    assert r.config_changes()[0]["changes"] == {"speed_factor": [60, 120]}


def test_reader_needs_an_existing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="history file not found"):
        HistoryReader(tmp_path / "missing.sqlite")


def test_who_wrote_an_explanation_is_kept_and_an_older_file_gains_the_columns(tmp_path, plant, lcopt5):
    from lcmesh.mesh.messages import Explanation

    path = tmp_path / "old.sqlite"
    with sqlite3.connect(path) as conn:  # a file written before the who-wrote-it columns
        conn.execute("CREATE TABLE explanations (id INTEGER PRIMARY KEY AUTOINCREMENT, decision_id TEXT NOT NULL, "
                     "step INTEGER NOT NULL, controller TEXT NOT NULL, level TEXT NOT NULL, text TEXT NOT NULL, "
                     "facts TEXT NOT NULL, source TEXT NOT NULL, created_at TEXT NOT NULL)")  # fmt: skip
        conn.execute("INSERT INTO explanations (decision_id, step, controller, level, text, facts, source, created_at) "
                     "VALUES ('d0', 0, 'g36', 'short', 'old text', '[]', 'control', '2026-01-01T00:00:00')")
    w = HistoryWriter(path)
    w.start_run("run1", lcopt5.name, lcopt5.content_hash(), "trace-x")
    w.record_step(None, _state(plant, lcopt5, 0), payload=False, checkpoint=None)
    for k in range(3):
        w.record_step(_applied(plant, k), _state(plant, lcopt5, k + 1), payload=False, checkpoint=None)
    w.add_explanation(Explanation(source="control", decision_id="d1", step=1, controller="g36", level="short",
                                  text="rendering\n\n## WHAT IF\n\nnear 30.1 °C", written_by="llm", llm_part="what-if"))
    w.add_explanation(Explanation(source="control", decision_id="d2", step=2, controller="g36", level="short",
                                  text="rendering", why_renderer="timeout"))  # fmt: skip
    by_id = {d["decision_id"]: d for d in HistoryReader(path).decisions()}
    assert by_id["d0"]["explanation"] == "old text" and by_id["d0"]["explanation_written_by"] == "renderer"
    assert by_id["d1"]["explanation_written_by"] == "llm" and by_id["d1"]["explanation_llm_part"] == "what-if"
    assert by_id["d2"]["explanation_written_by"] == "renderer" and by_id["d2"]["explanation_why_renderer"] == "timeout"
    HistoryWriter(path).close()  # opening again adds nothing twice


_READ_ONLY_PROCESS = """
import sys
from lcmesh.mesh.history import HistoryReader, HistoryWriter
from lcmesh.mesh.messages import AgentEvent
print(len(HistoryReader(sys.argv[1]).agent_events(limit=1000)))
try:
    HistoryWriter(sys.argv[1]).add_event(AgentEvent(source="ui", kind="warning", role="ui", agent_id="ui"))
except Exception as exc:
    print("no write:", exc)
"""


def _read_as_a_reader(path: Path) -> list[str]:
    """What a process that may only read `path`'s folder sees: a read-only bind mount as root (what compose's ``:ro``
    does), the folder and files made read-only with chmod otherwise."""
    argv = [sys.executable, "-c", _READ_ONLY_PROCESS, str(path)]
    folder = str(path.parent)
    if os.geteuid() == 0:
        if shutil.which("unshare") is None:
            pytest.skip("root without unshare: no way to make a read-only folder for root")
        argv = ["unshare", "-m", "sh", "-c", 'mount --bind -o ro "$0" "$0" && exec "$@"', folder, *argv]
        done = subprocess.run(argv, capture_output=True, text=True, timeout=60)
        if "mount" in done.stderr and done.returncode != 0:
            pytest.skip(f"no read-only bind mount here: {done.stderr.strip()}")
    else:
        files = [p for p in path.parent.iterdir()]
        for p in files:
            os.chmod(p, 0o444)
        os.chmod(folder, 0o555)
        try:
            done = subprocess.run(argv, capture_output=True, text=True, timeout=60)
        finally:
            os.chmod(folder, 0o700)
            for p in files:
                os.chmod(p, 0o600)
    assert done.returncode == 0, done.stderr
    return done.stdout.splitlines()


def test_readers_on_a_read_only_folder_read_while_the_writer_runs_and_after_it_closed(tmp_path):
    """Compose mounts history ``:ro`` for every agent but the Sensor: they read it live (WAL, the writer's -shm)
    and once the writer has closed the file (SQLite removed -wal and -shm, which they can not create), and they
    can not write a row."""
    path = tmp_path / "history" / "history.sqlite"
    w = HistoryWriter(path)
    for i in range(3):
        w.add_event(AgentEvent(source="sensor", kind="started", role="sensor", agent_id="sensor", detail=f"e{i}"))
    live = _read_as_a_reader(path)
    assert live[0] == "3" and live[1].startswith("no write:"), live
    w.add_event(AgentEvent(source="sensor", kind="warning", role="sensor", agent_id="sensor"))
    w.close()
    assert not path.with_name(path.name + "-wal").exists()
    closed = _read_as_a_reader(path)
    assert closed[0] == "4" and closed[1].startswith("no write:"), closed
    assert len(HistoryReader(path).agent_events()) == 4, "nothing was written by the readers"


def test_a_config_version_is_audited_once(tmp_path):
    """The Sensor records each config document it sees; one published again (a restarted Configuration agent)
    keeps its first audit row."""
    w = HistoryWriter(tmp_path / "h.sqlite")
    doc = ConfigDoc(source="configuration", version=2, config=MeshConfig(speed_factor=120), changed_by="ui/a",
                    reason="first", changes={"speed_factor": [60.0, 120.0]})
    w.add_config_change(doc)
    w.add_config_change(doc.model_copy(update={"changes": {"*": [None, "re-published"]}, "reason": "again"}))
    rows = HistoryReader(tmp_path / "h.sqlite").config_changes()
    assert [(r["version"], r["reason"], r["changes"]) for r in rows] == [(2, "first", {"speed_factor": [60.0, 120.0]})]
