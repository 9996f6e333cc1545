"""The systemd unit in deploy/systemd parses, is sandboxed, and runs the command and exit codes the mesh has."""

from __future__ import annotations

import configparser
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lcmesh.mesh.processes import SECRET_VARIABLES
from lcmesh.mesh.service import EXIT_BUSY

UNIT = Path(__file__).resolve().parents[2] / "deploy" / "systemd" / "lcmesh.service"
REPO_IN_UNIT = "/opt/lc-mesh"
VENV = Path(sys.executable).parent.parent


def _unit_here(tmp_path: Path) -> Path:
    """The unit with its install folder replaced by this checkout (systemd-analyze checks ExecStart exists)."""
    text = UNIT.read_text().replace(f"{REPO_IN_UNIT}/.venv", str(VENV)).replace(REPO_IN_UNIT, str(UNIT.parents[2]))
    path = tmp_path / UNIT.name
    path.write_text(text)
    return path


def _service_section() -> configparser.SectionProxy:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read(UNIT)
    return parser["Service"]


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed (Debian: systemd)")
def test_the_unit_parses_without_a_warning_and_is_sandboxed(tmp_path):
    unit = _unit_here(tmp_path)
    verify = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0 and verify.stderr.strip() == "", verify.stderr  # unknown keys only warn
    security = subprocess.run(["systemd-analyze", "security", "--offline=yes", str(unit)], capture_output=True,
                              text=True, timeout=60)  # fmt: skip
    level = re.search(r"Overall exposure level for \S+: ([\d.]+)", security.stdout)
    assert level, security.stdout[-500:] + security.stderr
    assert float(level.group(1)) <= 2.5, f"exposure {level.group(1)} (0 = locked down, 10 = none; 1.9 when written)"


def test_the_unit_runs_the_demo_and_does_not_restart_a_busy_one():
    service = _service_section()
    argv = service["ExecStart"].split()
    assert argv[0] == f"{REPO_IN_UNIT}/.venv/bin/lcmesh" and argv[1] == "demo"
    shown = subprocess.run([str(VENV / "bin" / "lcmesh"), *argv[1:], "--help"], capture_output=True, text=True,
                           timeout=60)  # fmt: skip
    assert shown.returncode == 0 and "--data-dir" in shown.stdout, "ExecStart's options are the demo's"
    assert str(EXIT_BUSY) in service["RestartPreventExitStatus"].split(), "a held port is not restarted in a loop"
    assert service["KillMode"] == "mixed", "SIGTERM to the demo alone: it stops its children in order"
    state_dir = service["StateDirectory"]
    assert f"--data-dir /var/lib/{state_dir}" in service["ExecStart"], "the data dir is the unit's state directory"


def test_the_unit_names_no_secret_and_keeps_its_state_private():
    """Secrets reach the demo through the 0600 env file alone; it hands each child its own role's files
    (tests/mesh/test_security.py::test_each_child_gets_only_its_own_roles_secrets) in a 0700 state folder."""
    service = _service_section()
    lines = [line for line in UNIT.read_text().splitlines() if line.startswith(("Environment=", "ExecStart="))]
    assert not [line for line in lines for name in SECRET_VARIABLES if name in line], lines
    assert service["EnvironmentFile"].lstrip("-").startswith("/etc/lcmesh/")
    assert service["StateDirectoryMode"] == "0700" and service["UMask"] == "0077"
