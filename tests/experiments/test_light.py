"""The light study (exposure and blur of the frame) runs end to end and reports every row."""

from __future__ import annotations

from pathlib import Path

from spotnav.experiments import light, reproduce


def test_light_study_smoke(tmp_path: Path) -> None:
    experiments = reproduce(tmp_path, size_px=384, poses=1, workers=1, only=["light"], log=print)
    report = (tmp_path / "report.md").read_text()
    for stops in light.EXPOSURE_STOPS:
        assert f"| exposure {stops:+.1f} stops" in report
    for blur_px in light.FRAME_BLURS_PX:
        assert f"| blur {blur_px:.1f} px | " in report
    # The thesis's exposure is answered; a blur of 3 px after the encoding leaves the edge unknown: refused.
    assert "| exposure +4.5 stops | 1/1 | " in report
    refused = "- (no ok frame: 0/1; blurred 1)"  # a missing figure says why
    assert f"| blur 3.0 px | 0/1 | {refused} | {refused} | {refused} | blurred 1 |" in report
    assert experiments[0].summary.startswith("light: exposure: 5/5 frames ok, max error ")
