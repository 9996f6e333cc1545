from __future__ import annotations

import pytest

from lcmesh.mesh import keys


def test_keys_follow_the_design_layout():
    assert keys.plant_state("s1") == "lcmesh/s1/plant/state"
    assert keys.proposal("s1") == "lcmesh/s1/control/plant/proposal"
    assert keys.applied("s1", "cab3") == "lcmesh/s1/control/cab3/applied"
    assert keys.explain("s1", "abc") == "lcmesh/s1/explain/abc"
    assert keys.alerts("s1") == "lcmesh/s1/maintenance/alerts"
    assert keys.monitor_report("s1") == "lcmesh/s1/monitor/report"
    assert keys.config("s1", "guardrails") == "lcmesh/s1/config/guardrails"
    assert keys.tool("s1", "whatif", "ui") == "lcmesh/s1/tools/whatif/ui"  # asked as the role (Security)
    assert keys.tool_served("s1", "whatif") == "lcmesh/s1/tools/whatif/*"
    assert keys.cmd("s1", "sensor", "inject_fault") == "lcmesh/s1/cmd/sensor/inject_fault"
    assert keys.alive("s1", "sensor", "sensor-2") == "lcmesh/s1/alive/sensor/sensor-2"


@pytest.mark.parametrize("bad", ["*", "a/b", "$x", "", "**", "a b", "-lead"])
def test_segments_that_would_change_a_key_are_refused(bad):
    with pytest.raises(ValueError, match="`site` must be"):
        keys.plant_state(bad)


def test_parse_alive_round_trips_and_rejects_other_keys():
    assert keys.parse_alive(keys.alive("s", "control", "c1")) == ("control", "c1")
    assert keys.parse_alive("lcmesh/s/plant/state") is None
    assert set(keys.all_keys("s")) >= {"plant_state", "proposal", "applied", "alive", "config", "tool", "cmd"}
