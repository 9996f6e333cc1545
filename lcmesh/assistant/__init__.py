"""The operator assistant: understand (question -> typed Query), plan (Query -> tool calls), run, write, check.

The UI agent serves it over HTTP (``lcmesh/mesh/agents/ui``); the stages live here (docs/ui.md "The assistant").
"""
