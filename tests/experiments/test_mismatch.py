from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from spotnav.experiments.mismatch import MISMATCH_CASES, SILENT_MM, SILENT_SIGMAS
from spotnav.experiments.scenes import thesis_world, with_true_edge
from spotnav.optics.render import Renderer
from spotnav.pose.localize import localize
from spotnav.setup.geometry import InstrumentPose
from spotnav.setup.uncertainty import Uncertainty

# What three beams' frames show of their own: a light unlike the setup's (the edge angle, the blend, the beams'
# tilt) bends their edges as no noise does (docs/methods.md, the precise method's 8).
SHOWN_BY_THREE_BEAMS = ("beam half-angle", "blend", "beam tilt")


# Known gap (issue 42): at 512 px, beams tilted 0.5 deg less than the setup says leave residuals 2.1 times their
# noise; counted as a shift of the edges they widen sigma to 0.028 mm, while the tip is 0.10 mm off. A beam's tilt
# is not an edge shift; the excess counted in full (over the noise, not 1.5 times it) covers it, but refuses
# matching 512 px frames whose ratio is just over 1.5.
_KNOWN_GAP = pytest.mark.xfail(strict=True, reason="a beam tilt's residuals widen sigma too little at 512 px")
CASES = [
    pytest.param(case, beams, id=f"{case.name}-{beams}", marks=[_KNOWN_GAP] * (case.name == "beam tilt -0.5 deg"))
    for case in MISMATCH_CASES
    for beams in case.beams
]


@pytest.mark.parametrize(("case", "beams"), CASES)
def test_a_world_one_quantity_off_is_caught_or_covered(case: object, beams: int) -> None:
    """One frame of a world one quantity off from the setup, 512 px: with the setup as a user writes it (a real
    microscope's ``[uncertainty]``) refused or answered within 3 sigma and not silently wrong; with the setup
    stated exactly, three beams refuse what their light shows, or widen sigma over it."""
    world = case.change(thesis_world(512, beams))  # type: ignore[attr-defined]
    pose = InstrumentPose.through_insertion(np.array([0.8, -0.6, 4.5]), world.instrument.insertion_in_eye)
    image = Renderer(world).render(pose, seed=42)
    as_known = localize(image, replace(thesis_world(512, beams), uncertainty=Uncertainty()), "precise")
    if as_known.ok:
        error = float(np.linalg.norm(as_known.pose()[0] - pose.tip_in_eye))
        assert error <= min(SILENT_MM, 3 * as_known.sigma_mm), as_known
    else:
        assert as_known.status in ("uncalibrated", "mismatch", "miscalibrated"), as_known
        assert "calibrate" in as_known.detail
    exact = localize(image, with_true_edge(thesis_world(512, beams)), "precise")
    name = case.name  # type: ignore[attr-defined]
    if name == "none":
        assert exact.ok and np.linalg.norm(exact.pose()[0] - pose.tip_in_eye) < SILENT_SIGMAS * exact.sigma_mm
    elif beams == 3 and name.startswith(SHOWN_BY_THREE_BEAMS):  # refused, or its residuals widened sigma to cover it
        if exact.ok:
            error = float(np.linalg.norm(exact.pose()[0] - pose.tip_in_eye))
            assert error <= min(SILENT_MM, 3 * exact.sigma_mm) and exact.fit_ratio > 1.5, (error, exact)
        else:
            assert exact.status in ("mismatch", "miscalibrated"), exact
