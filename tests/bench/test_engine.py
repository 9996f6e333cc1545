"""The benchmark engine: Ray gives the serial run's table row for row; the result cache keys by content, resumes a
stopped run, never keeps a failure, and `--fresh` recomputes; no Ray process outlives the run."""

from __future__ import annotations

import json
import sqlite3

import psutil
import pytest
from typer.testing import CliRunner

from lcmesh.bench.engine import EngineSettings, ResultCache, Unit, cache_line, run_units, tree_digest
from lcmesh.bench.suite import days_named, run_hru, run_suite
from lcmesh.cli import app

TINY = (["static", "g36"], days_named(["frontier", "hot-1033"]), 0.25)


def _rows(result: dict) -> dict:
    """Every figure of every controller and day, wall time aside (it is the machine's, not the result's)."""
    return {name: {day: {k: v for k, v in row.items() if k != "wall_s"} for day, row in e["days"].items()}
            for name, e in result["controllers"].items()}  # fmt: skip


def _ray_processes() -> list[str]:
    return [p.info["name"] for p in psutil.process_iter(["name"]) if p.info["name"] in ("raylet", "gcs_server")]


def test_ray_gives_the_serial_table_row_for_row_and_stops_what_it_started(tmp_path):
    pytest.importorskip("ray")
    import ray

    names, days, hours = TINY
    serial = run_suite(names, days=days, hours=hours, reference="g36",
                       engine=EngineSettings(engine="serial", cache=None))  # fmt: skip
    before = _ray_processes()
    on_ray = run_suite(names, days=days, hours=hours, reference="g36",
                       engine=EngineSettings(engine="ray", num_cpus=2, cache=tmp_path / "units.sqlite"))  # fmt: skip
    assert _rows(on_ray) == _rows(serial)
    assert on_ray["controllers"]["g36"]["regret"] == serial["controllers"]["g36"]["regret"]
    assert on_ray["cache"]["computed"] == 4 and on_ray["cache"]["cached"] == 0
    assert not ray.is_initialized()
    assert _ray_processes() == before  # the local instance it started is gone


def test_a_second_run_reads_every_unit_from_the_cache(tmp_path):
    names, days, hours = TINY
    settings = EngineSettings(engine="serial", cache=tmp_path / "units.sqlite")
    first = run_suite(names, days=days, hours=hours, reference="g36", engine=settings)
    second = run_suite(names, days=days, hours=hours, reference="g36", engine=settings)
    assert second["cache"]["cached"] == 4 and second["cache"]["computed"] == 0
    assert _rows(second) == _rows(first)
    assert "4 of 4 units from the result cache" in cache_line(second["cache"])
    assert second["controllers"]["g36"]["cached_days"] == 2
    # a longer day is another unit; --fresh recomputes what the cache holds
    longer = run_suite(["static"], days=days[:1], hours=0.5, reference="static", engine=settings)
    assert longer["cache"]["computed"] == 1
    fresh = run_suite(names, days=days, hours=hours, reference="g36",
                      engine=EngineSettings(engine="serial", cache=settings.cache, fresh=True))  # fmt: skip
    assert fresh["cache"]["computed"] == 4 and _rows(fresh) == _rows(first)


def test_both_systems_of_the_hru_table_go_in_one_submission(tmp_path):
    seen = []
    r = run_hru(["static"], days_named(["frontier"]), hours=0.25, progress=lambda s, d, t: seen.append((d, t)),
                engine=EngineSettings(engine="serial", cache=tmp_path / "u.sqlite"))  # fmt: skip
    assert seen[-1] == (2, 2) and r["cache"]["units"] == 2
    assert r["rows"]["static"]["heat_recovered_kwh"] > 0


def _units(n: int) -> list[Unit]:
    return [Unit("json:dumps", {"obj": [i, "x"]}, label=f"unit {i}") for i in range(n)]


def test_a_stopped_run_resumes_where_it_stopped(tmp_path):
    settings = EngineSettings(engine="serial", cache=tmp_path / "units.sqlite")

    def stop_after_two(stage: str, done: int, total: int) -> None:
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_units(_units(5), settings, progress=stop_after_two)
    out = run_units(_units(5), settings)
    assert [o.cached for o in out] == [True, True, False, False, False]
    assert [o.result for o in out] == [json.dumps([i, "x"]) for i in range(5)]


def test_a_failed_unit_is_reported_and_never_cached(tmp_path):
    settings = EngineSettings(engine="serial", cache=tmp_path / "units.sqlite")
    units = [Unit("json:loads", {"s": "[1, 2]"}, label="good"), Unit("json:loads", {"s": "{bad"}, label="bad")]
    first = run_units(units, settings)
    assert first[0].result == [1, 2] and first[0].error is None
    assert first[1].result is None and first[1].error.startswith("JSONDecodeError")
    again = run_units(units, settings)
    assert again[0].cached and not again[1].cached and again[1].error is not None


def test_a_damaged_cache_row_is_recomputed(tmp_path):
    settings = EngineSettings(engine="serial", cache=tmp_path / "units.sqlite")
    unit = _units(1)[0]
    run_units([unit], settings)
    with sqlite3.connect(settings.cache) as db:
        db.execute("UPDATE units SET result = '{not json' WHERE key = ?", (unit.key,))
    out = run_units([unit], settings)
    assert not out[0].cached and out[0].result == json.dumps([0, "x"])
    assert ResultCache(settings.cache).get(unit.key)[0] == json.dumps([0, "x"])


def test_a_key_changes_with_the_arguments_and_with_what_it_depends_on(tmp_path):
    a = Unit("json:dumps", {"obj": 1}, label="a", versions=("twin:1",))
    assert a.key == Unit("json:dumps", {"obj": 1}, label="renamed", versions=("twin:1",)).key
    assert a.key != Unit("json:dumps", {"obj": 2}, label="a", versions=("twin:1",)).key
    assert a.key != Unit("json:dumps", {"obj": 1}, label="a", versions=("twin:2",)).key
    (tmp_path / "model.json").write_text("{}")
    before = tree_digest(tmp_path)
    (tmp_path / "model.json").write_text('{"w": 1}')
    assert tree_digest(tmp_path) != before


def test_the_cli_refuses_bad_engine_options(tmp_path):
    runner = CliRunner()
    bad = runner.invoke(app, ["bench", "suite", "--controllers", "static", "--days", "frontier", "--engine", "spark"])
    assert bad.exit_code == 2 and "`--engine`" in bad.output and "ray" in bad.output
    mixed = runner.invoke(app, ["bench", "suite", "--controllers", "static", "--engine", "serial",
                                "--address", "127.0.0.1:6379"])  # fmt: skip
    assert mixed.exit_code == 2 and "--address" in mixed.output
    folder = runner.invoke(app, ["bench", "suite", "--controllers", "static", "--cache", str(tmp_path)])
    assert folder.exit_code == 2 and "SQLite file" in folder.output


def test_the_longest_units_go_first(tmp_path):
    from lcmesh.bench.engine import longest_first

    units = [Unit("json:dumps", {"obj": i}, label=f"u{i}", cost=c) for i, c in enumerate((1.0, 10.0, 1.0, 5.0))]
    assert longest_first([0, 1, 2, 3], units, {}) == [1, 3, 0, 2]  # no history: the cost guesses
    history = {"u0": 9.0, "u1": 0.5, "u2": 3.0, "u3": 1.0}
    assert longest_first([0, 1, 2, 3], units, history) == [0, 2, 3, 1]  # the cache's times of the same labels
    cache = ResultCache(tmp_path / "units.sqlite")
    cache.put(units[2], "r", "abc", 3.0)
    assert cache.last_seconds(["u2", "u9"]) == {"u2": 3.0}
