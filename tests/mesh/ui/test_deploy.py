"""The provisioned Grafana dashboard and the Prometheus config match what /metrics exposes."""

from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[3]
PROMQL_FUNCTIONS = {"max", "min", "sum", "rate", "by", "histogram_quantile", "le", "avg"}


def test_every_dashboard_query_uses_an_exposed_metric(api):
    from prometheus_client.parser import text_string_to_metric_families

    exposed = set()
    suffixes = {"counter": ("_total",), "histogram": ("_bucket", "_count", "_sum"), "gauge": ("",)}
    for family in text_string_to_metric_families(api.get("/metrics").text):  # families are listed even when empty
        exposed.update(family.name + suffix for suffix in suffixes.get(family.type, ("",)))
    dashboard = json.loads((ROOT / "deploy/grafana/dashboards/lcmesh.json").read_text())
    assert dashboard["uid"] and len(dashboard["panels"]) >= 10
    used = set()
    for panel in dashboard["panels"]:
        assert panel["datasource"]["uid"] == "lcmesh-prometheus"
        for target in panel["targets"]:
            used.update(n for n in re.findall(r"\blcmesh_[a-z_]+", target["expr"]) if n not in PROMQL_FUNCTIONS)
    missing = sorted(used - exposed)
    assert not missing, f"dashboard queries metrics /metrics does not expose: {missing}"
    assert {"lcmesh_blade_temperature_celsius", "lcmesh_cooling_tower_fan_power_watts", "lcmesh_agent_up"} <= used


def test_prometheus_and_grafana_provisioning_point_at_each_other():
    prom = yaml.safe_load((ROOT / "deploy/prometheus/prometheus.yml").read_text())
    job = prom["scrape_configs"][0]
    assert job["metrics_path"] == "/metrics" and job["static_configs"][0]["targets"] == ["ui:8000"]
    ds = yaml.safe_load((ROOT / "deploy/grafana/provisioning/datasources/prometheus.yml").read_text())["datasources"][0]
    assert ds["uid"] == "lcmesh-prometheus" and ds["url"] == "http://prometheus:9090"
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())["services"]
    assert {"prometheus", "grafana", "ui"} <= set(compose)
    assert compose["ui"]["environment"]["LCMESH_API_TOKEN_FILE"], "the UI binds 0.0.0.0 in compose: it needs a token"
    scraped = job["static_configs"][0]["targets"][0]
    assert scraped in compose["ui"]["environment"]["LCMESH_UI_ALLOWED_HOSTS"], "the Host allow-list lets Prometheus in"
