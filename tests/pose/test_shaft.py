"""Shaft occlusion: which edge points the instrument's shaft hides."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.camera import project_points
from spotnav.pose.shaft import hidden_by_shaft

ABOVE = (0.0, 1.0, 24.0)  # an insertion point above the working volume: the shaft crosses the spot


def _world() -> object:
    world = thesis_world(768, 1)
    return with_true_edge(replace(world, instrument=replace(world.instrument, insertion_point_mm=ABOVE)))


def test_hidden_by_shaft_marks_the_points_under_the_shaft_only() -> None:
    world = _world()
    tip, insertion = np.array([0.5, 0.5, 4.0]), world.instrument.insertion_in_eye
    axis = (tip - insertion) / np.linalg.norm(tip - insertion)
    on_shaft = project_points(world.camera, tip + np.outer([-0.5, -1.0, -2.0], axis))
    aside = on_shaft + np.array([0.0, 200.0])
    hidden = hidden_by_shaft(world, [on_shaft, aside], tip, axis)
    assert hidden[0].all() and not hidden[1].any()
    no_shaft = replace(world, instrument=replace(world.instrument, shaft_diameter_mm=0.0))
    assert not hidden_by_shaft(no_shaft, [on_shaft], tip, axis)[0].any()
