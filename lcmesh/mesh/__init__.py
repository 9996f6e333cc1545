"""The agent mesh: Zenoh bus, messages, agents, toolbox."""
