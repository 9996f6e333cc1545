"""schemathesis, the OpenAPI fuzzer, against the UI served by uvicorn on a real mesh: every check, no failure.

It reads the UI's own /openapi.json, generates valid and invalid requests for every operation and
checks every answer: no 500, only documented status codes, bodies and headers as documented,
invalid input refused, valid input accepted, 405 with the right `Allow`, auth enforced. The
command line is the one an operator would type (settings in schemathesis.toml beside this file):

    st --config-file tests/mesh/ui/schemathesis.toml run http://127.0.0.1:8000/openapi.json \\
       --checks all --max-examples 25 --header "Authorization: Bearer $(cat runs/mesh/ui/api-token)"

The quick test fuzzes the session's mesh without the token (the writes answer 401, which is
what an unauthenticated fuzzer must see); the slow one a mesh of its own with the token, so
configuration changes, controller switches and manual setpoints are fuzzed too (that mesh runs
no Control agent: a fuzzed controller switch must not load an LLM on the test machine).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.mesh.ui.conftest import running_mesh

ST = Path(sys.executable).with_name("st")
CONFIG = Path(__file__).with_name("schemathesis.toml")


def schemathesis(url: str, max_examples: int, workdir: Path, token: str | None = None) -> tuple[int, str]:
    """Run ``st run`` with every check on `url`; (exit status, output)."""
    command = [str(ST), "--config-file", str(CONFIG), "--no-color", "run", f"{url}/openapi.json", "--checks", "all",
               "--max-examples", str(max_examples), "--seed", "1", "--workers", "1", "--request-timeout", "30"]  # fmt: skip
    if token is not None:
        command += ["--header", f"Authorization: Bearer {token}"]
    done = subprocess.run(command, cwd=workdir, capture_output=True, text=True, timeout=1500)
    return done.returncode, done.stdout + done.stderr


def _assert_clean(status: int, out: str, operations: int) -> None:
    tested = re.search(r"Tested:\s+(\d+)", out)
    cases = re.search(r"(\d+) generated, (\d+) passed", out)
    assert status == 0, out[-6000:]
    assert tested and int(tested.group(1)) == operations, out[-3000:]
    assert cases and cases.group(1) == cases.group(2) and int(cases.group(1)) >= 5 * operations, out[-3000:]


@pytest.mark.skipif(not ST.exists(), reason="schemathesis is not installed (pip install -e '.[test]')")
def test_schemathesis_finds_nothing_without_the_token(ui_mesh, api, tmp_path):
    operations = sum(len(methods) for methods in api.get("/openapi.json").json()["paths"].values())
    status, out = schemathesis(ui_mesh.url, 5, tmp_path)
    _assert_clean(status, out, operations)


@pytest.mark.slow
@pytest.mark.timeout(1800)
@pytest.mark.skipif(not ST.exists(), reason="schemathesis is not installed (pip install -e '.[test]')")
def test_schemathesis_finds_nothing_with_the_token(tmp_path):
    with running_mesh(tmp_path / "mesh", roles=("configuration", "sensor", "maintenance", "monitor")) as mesh:
        with mesh.client() as http:
            operations = sum(len(methods) for methods in http.get("/openapi.json").json()["paths"].values())
            status, out = schemathesis(mesh.url, 25, tmp_path, token=mesh.token)
            assert http.get("/api/health").json()["ready"], "the UI still answers after the fuzzing"
    print(out[-2500:])  # the summary, for the record (pytest -s)
    _assert_clean(status, out, operations)
    assert "Authentication failed" not in out
