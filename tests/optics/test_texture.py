from __future__ import annotations

import numpy as np

from spotnav.optics.texture import make_texture, sample_albedo


def test_texture_is_seeded_and_in_range() -> None:
    first = make_texture("retina", 0)
    assert first is make_texture("retina", 0)  # cached
    other = make_texture("retina", 1)
    assert first.rgb.dtype == np.float32
    assert 0.0 <= first.rgb.min() and first.rgb.max() <= 1.0
    assert not np.array_equal(first.rgb, other.rgb)
    assert not first.rgb.flags.writeable


def test_retina_has_red_fundus_with_dark_vessels() -> None:
    rgb = make_texture("retina", 0).rgb
    median = np.median(rgb.reshape(-1, 3), axis=0)
    assert median[0] > median[1] > median[2]  # orange-red
    red = rgb[..., 0]
    assert np.percentile(red, 0.5) < 0.75 * median[0]  # vessels and fovea darken it


def test_flat_texture_is_uniform_and_sampling_is_bilinear() -> None:
    flat = make_texture("flat", 0)
    x = np.array([[0.0, 3.2], [-4.0, np.nan]])
    albedo = sample_albedo(flat, x, np.zeros_like(x))
    np.testing.assert_allclose(albedo[0, 0], flat.rgb[0, 0], rtol=1e-6)
    np.testing.assert_allclose(albedo[1, 1], 0.0)
