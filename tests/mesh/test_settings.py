from __future__ import annotations

import pytest
from pydantic import ValidationError

from lcmesh.mesh.settings import MeshSettings


def test_env_prefix_comma_lists_and_nested_components(monkeypatch):
    monkeypatch.setenv("LCMESH_SITE", "plant-b")
    monkeypatch.setenv("LCMESH_ROUTER_ENDPOINTS", "tcp/127.0.0.1:7001, tcp/127.0.0.1:7002")
    monkeypatch.setenv("LCMESH_SENSOR__DEADLINE_FRACTION", "0.5")
    monkeypatch.setenv("LCMESH_SPEED_FACTOR", "120")
    s = MeshSettings()
    assert s.site == "plant-b"
    assert s.router_endpoints == ["tcp/127.0.0.1:7001", "tcp/127.0.0.1:7002"]
    assert s.sensor.deadline_fraction == 0.5
    assert s.speed_factor == 120.0
    assert s.history_file == s.data_dir / "history.sqlite"


def test_to_env_round_trips(monkeypatch, tmp_path):
    original = MeshSettings(site="x1", router_endpoints=["tcp/127.0.0.1:7100"], data_dir=tmp_path,
                            sensor={"hold_periods": 5}, orchestration={"roles": ["sensor", "control"]})
    for name, value in original.to_env().items():
        monkeypatch.setenv(name, value)
    again = MeshSettings()
    assert again == original


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("router_endpoints", ["127.0.0.1:7447"], "`router_endpoints` entries must look like 'tcp/HOST:PORT'"),
        ("site", "a/b", "site"),
        ("speed_factor", 0, "speed_factor"),
        ("sensor", {"deadline_fraction": 2}, "deadline_fraction"),
    ],
)
def test_bad_settings_name_the_field(field, value, message):
    with pytest.raises(ValidationError, match=message):
        MeshSettings(**{field: value})
