"""``python -m lcmesh.mesh.agents ROLE [--id ID]``: one agent process (what the Orchestrator spawns).

The same as ``lcmesh agent ROLE`` without loading the command-line app, so restarts are quick.
"""

from __future__ import annotations

import argparse
import sys

from lcmesh.mesh.agents.registry import ROLES
from lcmesh.mesh.agents.runner import run_agent
from lcmesh.mesh.processes import tie_to_parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m lcmesh.mesh.agents", description=__doc__)
    parser.add_argument("role", choices=sorted(ROLES))
    parser.add_argument("--id", dest="agent_id", default=None, help="agent id (default: the role)")
    args = parser.parse_args(argv)
    tie_to_parent()  # started by an orchestrator: end with it, however it ends
    return run_agent(args.role, agent_id=args.agent_id)


if __name__ == "__main__":
    sys.exit(main())
