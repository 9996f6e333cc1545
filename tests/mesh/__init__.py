"""Tests of lcmesh.mesh."""
