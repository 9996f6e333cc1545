"""Tests of lcmesh.mesh.tools."""
