"""System descriptions: reference systems, user descriptions, clear errors."""

from __future__ import annotations

import json

import pytest

from lcmesh.twin.system import SystemDescriptionError, load_system, parse_system, reference_systems


def test_reference_systems_have_the_papers_shapes():
    assert {"lcopt-5", "lcopt-10", "lcopt-15", "lcopt-20", "lcopt-25", "frontier-full"} <= set(reference_systems())
    # LC-Opt Tables 3 and 4: (N towers, C cabinets); m = 2 cells, B = 3 blade groups throughout
    for name, towers, cabinets in [("lcopt-5", 2, 5), ("lcopt-10", 2, 10), ("lcopt-15", 2, 15),
                                   ("lcopt-20", 3, 20), ("lcopt-25", 4, 25)]:  # fmt: skip
        s = load_system(name)
        assert (s.towers.count, s.towers.cells, s.cabinets.count, s.cabinets.branches) == (towers, 2, cabinets, 3)
    full = load_system("frontier-full")
    assert full.cabinets.count == 25 and 9_000 <= full.n_blade_groups <= 11_000
    assert load_system("lcopt-5-hru").heat_recovery is not None


def test_a_user_description_from_a_file(tmp_path):
    desc = {"name": "my-site", "cabinets": {"count": 7, "branches": 4, "blade_groups_per_branch": 2},
            "towers": {"count": 3, "cells": 3}}  # fmt: skip
    path = tmp_path / "my-site.json"
    path.write_text(json.dumps(desc))
    s = load_system(path)
    assert (s.n_cabinets, s.n_branches, s.n_blade_groups, s.n_cells) == (7, 28, 56, 9)


@pytest.mark.parametrize(
    "patch, field",
    [
        ({"cabinets": {"count": 0, "branches": 3}}, "cabinets.count"),
        ({"cabinets": {"count": 2, "branches": 3, "blade_groups_per_branch": -1}}, "cabinets.blade_groups_per_branch"),
        ({"towers": {"count": 1, "cells": 2, "stage_up_speed": 0.2, "stage_down_speed": 0.5}}, "stage_down_speed"),
        ({"towers": {"count": 1, "cells": 2, "colour": "red"}}, "towers.colour"),
        ({"substeps": 1}, "substeps"),
    ],
)
def test_bad_descriptions_name_the_field(patch, field):
    desc = {"name": "bad", "cabinets": {"count": 2, "branches": 3}, "towers": {"count": 1, "cells": 2}, **patch}
    with pytest.raises(SystemDescriptionError, match=field.replace(".", r"\.")):
        parse_system(desc)


def test_unknown_system_suggests_the_closest_name():
    with pytest.raises(SystemDescriptionError, match="did you mean 'lcopt-5'"):
        load_system("lcopt5")


def test_malformed_json_is_a_clear_error(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{"name": "x", "cabinets": ')
    with pytest.raises(SystemDescriptionError, match="not valid JSON"):
        load_system(path)


def test_content_hash_tracks_every_field(lcopt5):
    changed = parse_system({**lcopt5.model_dump(), "load_skew_seed": 7})
    assert changed.content_hash() != lcopt5.content_hash()
    assert parse_system(lcopt5.model_dump()).content_hash() == lcopt5.content_hash()
