"""The UI agent: REST API, web page and the chat over HTTP (the assistant itself is ``lcmesh.assistant``)."""


def __getattr__(name: str):
    if name == "UiAgent":  # imported on use, so the assistant can import the gateway without the whole agent
        from lcmesh.mesh.agents.ui.agent import UiAgent

        return UiAgent
    raise AttributeError(name)


__all__ = ["UiAgent"]
