"""History retention in a real SQLite file: the size bound, tiers, age limits, resume, file modes."""

from __future__ import annotations

import os
import sqlite3
import stat
from datetime import timedelta

import pytest

from lcmesh.mesh.history import HistoryReader, HistoryWriter
from lcmesh.mesh.messages import (
    ActionModel, AgentEvent, Alert, AppliedAction, ConfigDoc, Explanation, FactModel, MeshConfig,
    plant_state_from_outputs, utc_now,
)  # fmt: skip
from lcmesh.mesh.retention import file_bytes
from lcmesh.mesh.settings import HistoryConfig, MeshSettings

# 53 facts and ~1.6 kB of text, like the Control agent's explanations in `lcmesh demo` (lcopt-5), where
# a step wrote ~16 kB in all: state payload ~5 kB, action ~1 kB, explanation ~9.6 kB
FACTS = [FactModel(name=f"branch_{i}_temp", value=30.0 + i / 7, unit="degC", kind="observation",
                   text=f"branch {i} runs at {30.0 + i / 7:.1f} °C and draws {40 + i:.1f} kW of the cabinet load")
         for i in range(53)]  # fmt: skip
STEP = timedelta(seconds=15)
TEXT = "Cabinet 2. Valve split: branch 1's valve is set to 0.13 for 13 % of the cabinet load. " * 18


class Steps:
    """Writes a run's steps the way the Sensor and Control agent do (state, action, explanation).

    Rows are stamped by a clock that starts at `start` and advances 15 s a step (a plant at 1x), so
    their ages do not depend on how fast this machine writes them.
    """

    def __init__(self, writer: HistoryWriter, plant, system, run_id: str = "run1", start=None):
        self.w, self.plant, self.system, self.run_id = writer, plant, system, run_id
        self.step, self.clock = 0, start or utc_now()
        writer.start_run(run_id, system.name, system.content_hash(), "trace-x")
        writer.record_step(None, self._state(0, self.clock), payload=True, checkpoint=(b"fmu0", "{}"))

    def _state(self, step, at):
        return plant_state_from_outputs(self.plant.out, source="sensor", system=self.system, run_id=self.run_id,
                                        step=step, time_s=15.0 * step, wet_bulb_k=290.0, period_s=0.25,
                                        blade_power_w=[1e4] * self.system.n_blade_groups).model_copy(
                                            update={"sent_at": at})  # fmt: skip

    def write(self, n: int, *, start=None, checkpoint_every: int = 1, each=None) -> None:
        self.clock = start or self.clock
        for _ in range(n):
            self.clock += STEP
            k, at = self.step, self.clock
            self.w.add_explanation(Explanation(source="control", sent_at=at, decision_id=f"{self.run_id}-d{k}",
                                               step=k, controller="tree", text=TEXT, facts=FACTS))  # fmt: skip
            applied = AppliedAction(source="sensor", sent_at=at, run_id=self.run_id, step=k, time_s=15.0 * k,
                                    decision_id=f"{self.run_id}-d{k}", source_controller="tree", source_version="1",
                                    action=ActionModel.from_action(self.plant.default_action()))  # fmt: skip
            ckpt = (f"fmu{k + 1}".encode(), "{}") if (k + 1) % checkpoint_every == 0 else None
            self.w.record_step(applied, self._state(k + 1, at), payload=True, checkpoint=ckpt)
            self.step += 1
            self.w.maintain()
            if each is not None:
                each()


def _count(path, sql):
    with sqlite3.connect(path) as conn:
        return conn.execute(sql).fetchone()[0]


def _bounded(max_mb=2.0, **overrides) -> HistoryConfig:
    # pass_budget_ms large: what a pass does must not depend on this machine's speed
    values = dict(max_mb=max_mb, keep_latest_steps=20, prune_every_steps=5, batch_rows=10, pass_budget_ms=60_000)
    return HistoryConfig(**{**values, **overrides})


def test_the_file_stays_under_its_bound_and_decisions_outlive_states(tmp_path, plant, lcopt5):
    path = tmp_path / "h.sqlite"
    w = HistoryWriter(path, retention=_bounded(max_mb=2.0))
    w.add_alert(Alert(source="maintenance", alert_id="al1", state="raised", kind="pump_degradation", location="cab 2"))
    w.add_event(AgentEvent(source="orchestration", kind="started", role="sensor", agent_id="sensor"))
    w.add_config_change(ConfigDoc(source="configuration", version=1, config=MeshConfig(), changed_by="settings"), {})
    steps = Steps(w, plant, lcopt5, start=utc_now() - 700 * STEP)
    sizes = []
    steps.write(700, each=lambda: sizes.append(file_bytes(path)))  # ~11 MB unbounded
    assert max(sizes) <= 2_000_000, f"history grew to {max(sizes)} B over its 2 MB bound"
    assert sizes[-1] > 1_000_000, "the bound is used, not pruned far below it"
    r = HistoryReader(path)
    assert r.latest_state().step == 700 and r.state_at(700) is not None, "the newest steps keep their payload"
    first_payload = _count(path, "SELECT MIN(step) FROM plant_states WHERE payload IS NOT NULL")
    first_state, first_action = r.first_step(), r.first_step("actions")
    assert 0 < first_action < first_state < first_payload, "decisions outlive states outlive payloads"
    # states and decisions keep about the same share of their age limits (168 h, 720 h): spans ~1 : 4.3;
    # payloads are down to the protected newest 20 steps, so tight is 2 MB for ~17 kB steps
    assert 700 - first_action > 3 * (700 - first_state) and first_payload == 700 - 20 + 1
    assert r.step_gaps() == [] and r.step_gaps("actions") == [], "pruning removes the oldest steps, no holes"
    assert r.decisions(limit=1000)[-1]["explanation"] == TEXT, "an old decision keeps its explanation text"
    assert r.explanations(limit=1000)[-1]["facts"] == [], "an old explanation lost its facts (the payload tier)"
    assert [a["alert_id"] for a in r.alerts()] == ["al1"], "audit rows outlive the decisions pruned here"
    assert len(r.agent_events()) == 1 and len(r.config_changes()) == 1


def test_age_limits_thin_then_drop_and_keep_the_newest_steps(tmp_path, plant, lcopt5):
    path = tmp_path / "h.sqlite"
    cfg = _bounded(max_mb=0, keep_payload_hours=1, keep_states_hours=24, keep_decisions_hours=72, keep_audit_hours=0,
                   keep_latest_steps=10, prune_every_steps=1)  # fmt: skip
    w = HistoryWriter(path, retention=cfg)
    now = utc_now()
    w.add_event(AgentEvent(source="o", sent_at=now - timedelta(hours=50), kind="started", role="sensor", agent_id="s"))
    steps = Steps(w, plant, lcopt5, start=now - timedelta(hours=50))
    steps.write(60)  # older than the states' limit, younger than the decisions'
    steps.write(30, start=now - timedelta(hours=2))  # older than the payload limit only
    steps.write(30, start=now - 30 * STEP)
    for _ in range(10):
        w.maintain()
    r = HistoryReader(path)
    assert r.first_step() == 61, "states written 50 h ago are gone (24 h limit)"
    assert r.first_step("actions") == 0, "decisions written 50 h ago are kept (72 h limit)"
    assert r.state_at(75) is None and r.states(start_step=75, end_step=75)[0]["step"] == 75, "2 h old: summary only"
    assert r.state_at(100) is not None and r.state_at(120) is not None, "recent steps keep their payload"
    assert len(r.agent_events()) == 1, "keep_audit_hours=0: no age limit"


def test_resume_checkpoint_survives_pruning_and_ended_runs_lose_theirs(tmp_path, plant, lcopt5):
    path = tmp_path / "h.sqlite"
    w = HistoryWriter(path, retention=_bounded(max_mb=1.0, keep_latest_steps=5))
    old = Steps(w, plant, lcopt5, run_id="old", start=utc_now() - 500 * STEP)
    old.write(20)
    w.end_run("old")
    steps = Steps(w, plant, lcopt5, run_id="run2", start=utc_now() - 450 * STEP)
    steps.write(400, checkpoint_every=50)  # the checkpoint lags the newest step by up to 49 steps
    ckpt = w.resumable(lcopt5.content_hash(), "trace-x")
    assert ckpt is not None and ckpt.run_id == "run2" and ckpt.step == 400 - 400 % 50 and ckpt.fmu_state == b"fmu400"
    steps.write(45, checkpoint_every=50)
    ckpt = w.resumable(lcopt5.content_hash(), "trace-x")
    assert ckpt.step == 400, "a checkpoint 45 steps old is kept"
    r = HistoryReader(path)
    assert r.first_step(run_id="run2") <= 400 - 5 + 1 and r.state_at(400, run_id="run2") is not None
    assert r.first_step(run_id="old") is None, "the ended run's states were pruned first"
    assert _count(path, "SELECT COUNT(*) FROM checkpoints") == 1, "the ended run's checkpoint is dropped"


def test_files_are_private(tmp_path, plant, lcopt5):
    path = tmp_path / "data" / "h.sqlite"
    w = HistoryWriter(path, retention=_bounded())
    Steps(w, plant, lcopt5).write(3)
    for p in (path, path.with_name("h.sqlite-wal"), path.with_name("h.sqlite-shm")):
        assert stat.S_IMODE(p.stat().st_mode) == 0o600, f"{p.name} is {oct(stat.S_IMODE(p.stat().st_mode))}"
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
    assert _count(path, "PRAGMA auto_vacuum") == 2, "incremental auto-vacuum, so pruning can shrink the file"
    w.close()
    legacy = tmp_path / "legacy.sqlite"
    sqlite3.connect(legacy).close()
    os.chmod(legacy, 0o644)
    HistoryWriter(legacy).close()
    assert stat.S_IMODE(legacy.stat().st_mode) == 0o600, "a file left world-readable by an older version is tightened"


def test_settings_from_the_environment(monkeypatch):
    monkeypatch.setenv("LCMESH_HISTORY__MAX_MB", "50")
    monkeypatch.setenv("LCMESH_HISTORY__KEEP_STATES_HOURS", "48")
    s = MeshSettings()
    assert s.history.max_mb == 50 and s.history.keep_states_hours == 48
    assert '"max_mb":50.0' in s.to_env()["LCMESH_HISTORY"], "child processes get the same retention"
    with pytest.raises(ValueError, match=r"`keep_states_hours` must be 0 \(no limit\) or >= `keep_payload_hours`"):
        HistoryConfig(keep_payload_hours=24, keep_states_hours=2)


def test_without_retention_maintain_does_nothing(tmp_path, plant, lcopt5):
    w = HistoryWriter(tmp_path / "h.sqlite")
    Steps(w, plant, lcopt5).write(12)
    assert w.maintain() is None and _count(tmp_path / "h.sqlite", "SELECT COUNT(*) FROM plant_states") == 13


def test_a_lower_bound_shrinks_the_file(tmp_path, plant, lcopt5):
    path = tmp_path / "h.sqlite"
    w = HistoryWriter(path, retention=_bounded(max_mb=0))
    Steps(w, plant, lcopt5, start=utc_now() - 300 * STEP).write(300)
    w.close()
    grown = file_bytes(path)
    w = HistoryWriter(path, retention=_bounded(max_mb=1.0, prune_every_steps=1))
    reports = [w.maintain() for _ in range(200)]  # ~16 vacuumed pages a pass
    assert grown > 4_000_000 and file_bytes(path) <= 1_000_000, f"{grown} B -> {file_bytes(path)} B"
    assert sum(r.vacuumed_pages for r in reports) > 0 and any(r.truncated_wal for r in reports)
    assert not reports[-1].over_bound
