"""The ``lcmesh`` command line (user-facing names fixed by DESIGN.md).

Each area registers its commands on the shared apps in its own module; importing the modules here wires them.
"""

from lcmesh.cli.common import app
from lcmesh.cli import api, chat, control, explain, llm, mesh, planner, tools, twin  # noqa: F401  (each registers)

__all__ = ["app"]
