"""The README: its Python example runs as written, it lists every document, and it says what a newcomer asks first."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).parents[1]
README = (ROOT / "README.md").read_text()


def test_readme_python_example_runs():
    code = re.search(r"```python\n(.*?)```", README, re.S).group(1)
    scope: dict = {}
    exec(compile(code, "README.md", "exec"), scope)
    env = scope["env"]
    obs, info = env.reset(seed=0)
    obs2, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert obs2.shape == obs.shape and info["time_s"] > 0
    env.close()


def test_readme_lists_every_document_and_each_link_resolves():
    section = README.split("## Documentation", 1)[1].split("\n## ", 1)[0]
    linked = re.findall(r"\]\((docs/[^)]+\.md)\)", section)
    assert all((ROOT / path).is_file() for path in linked), linked
    assert set(linked) == {f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")}, "a document missing from the list"


def test_readme_opens_with_make_and_says_ports_token_and_setup():
    from lcmesh.mesh.agents.ui.security import TOKEN_FILE_NAME
    from lcmesh.mesh.settings import MeshSettings

    first_block = re.search(r"```\n(.*?)```", README, re.S).group(1)
    assert first_block.startswith("make demo") and "make test" in first_block
    token_file = (MeshSettings.model_fields["data_dir"].default / "ui" / TOKEN_FILE_NAME).as_posix()  # where it is
    for words in ("LCMESH_UI_PORT", "--ui-port", "LCMESH_ROUTER_ENDPOINTS", "LCMESH_API_TOKEN", token_file,
                  "du -sh .venv", "make setup"):  # fmt: skip
        assert words in README, words
