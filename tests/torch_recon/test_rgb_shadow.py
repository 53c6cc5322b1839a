"""Intensity (RGB) shadows: ratio masks, the time integral of transients, label swapping."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import make_synthetic_dataset
from torch_recon.contract.dataset import DatasetError, Transient, load_dataset
from torch_recon.measurements import Measurements, SpotMeasurement
from torch_recon.rgb_shadow import (apply_intensity_shadows, integrated_intensity, intensity_shadow_masks,
                                    mask_agreement, read_rgb_luminance, srgb_to_linear)


def _three_spots():
    """3 spots on a 2 x 3 image, each lit at 10, spot 1 shadowed (0.5) at pixel (0, 1)."""
    i = np.full((3, 2, 3), 10.0)
    i[1, 0, 1] = 0.5
    return i


def test_ratio_threshold_is_exact():
    i = _three_spots()
    sh, lab = intensity_shadow_masks(i, 0.05)          # ratio 0.05 is not below 0.05
    assert lab.all() and not sh.any()
    sh, _ = intensity_shadow_masks(i, 0.0501)
    assert sh.sum() == 1 and sh[1, 0, 1]


def test_ambient_offset_washes_shadows_out():
    i = _three_spots()
    sh0, _ = intensity_shadow_masks(i, 0.5)
    assert sh0[1, 0, 1]
    for ambient, expect in ((2.0, True), (12.0, False)):     # (0.5 + a) / (10 + a): 0.21, 0.57
        sh, _ = intensity_shadow_masks(i + ambient, 0.5)
        assert bool(sh[1, 0, 1]) is expect and sh.sum() == int(expect)


def test_dark_and_nan_pixels_get_no_label():
    i = _three_spots()
    i[:, 1, 2] = 0.0            # dark in every spot
    i[:, 1, 0] = np.nan         # unreadable in every spot
    i[2, 0, 0] = np.nan         # one spot unreadable: no claim for it, the others still judged
    i[0, 0, 0] = 0.1
    sh, lab = intensity_shadow_masks(i, 0.15)
    assert not lab[1, 2] and not lab[1, 0] and lab[0, 0]
    assert not sh[:, 1, 2].any() and not sh[:, 1, 0].any()
    assert sh[0, 0, 0] and not sh[2, 0, 0]


def test_excluded_pixels_are_never_shadow_nor_reference():
    i = _three_spots()
    i[2, 1, 1] = 1e6            # the pixel seeing spot 2 directly: far brighter than any two-bounce light
    ex = np.zeros(i.shape, bool)
    ex[2, 1, 1] = True
    sh, _ = intensity_shadow_masks(i, 0.15)
    assert sh[0, 1, 1] and sh[1, 1, 1]         # without the exclusion, spot 2's glare 'shadows' the others
    sh, _ = intensity_shadow_masks(i, 0.15, ex)
    assert not sh[:, 1, 1].any()
    sh2, _ = intensity_shadow_masks(i, 0.15, ex[2])   # an (H, W) mask applies to every spot
    assert not sh2[:, 1, 1].any()


@pytest.mark.parametrize("args, match", [
    ((np.ones((2, 3)), 0.1), "intensities"),
    ((np.ones((2, 2, 3)), 1.5), "threshold"),
    ((np.ones((2, 2, 3)), 0.1, np.zeros((3, 3), bool)), "excluded"),
])
def test_bad_shapes_and_values_are_refused(args, match):
    with pytest.raises(ValueError, match=match):
        intensity_shadow_masks(*args)


def test_integrated_intensity_of_dense_and_windowed(tmp_path):
    rng = np.random.default_rng(3)
    cube = rng.poisson(2.0, (4, 5, 30)).astype(np.float32)
    np.testing.assert_allclose(integrated_intensity(Transient.from_dense(cube)), cube.sum(2, dtype=np.float64))
    win = Transient.from_dense(cube, 7)
    np.testing.assert_allclose(integrated_intensity(win), win.dense().sum(2, dtype=np.float64))
    assert (integrated_intensity(win) <= cube.sum(2) + 1e-6).all()       # light outside the window is lost
    _, cubes = make_synthetic_dataset(tmp_path / "ds")
    ds = load_dataset(tmp_path / "ds")
    for sid, dense in cubes.items():
        np.testing.assert_allclose(integrated_intensity(ds.read_transient(sid)), dense.sum(2, dtype=np.float64),
                                   rtol=1e-6)
    with pytest.raises(TypeError):
        integrated_intensity(cube)


def _meas(h=2, w=3):
    def spot(k, signal, shadow, excluded):
        path = np.where(signal, 4.0 + k, np.nan).astype(np.float32)
        return SpotMeasurement(spot_id=k, first_bounce=np.array([0.0, 2.0, -1.0]),
                               laser_direction=np.array([0.0, 1.0, 0.0]), path_length=path, signal=signal,
                               shadow_confidence=signal.astype(np.float32), shadow=shadow, excluded=excluded)
    sig = np.array([[1, 1, 0], [1, 1, 1]], bool)
    ex = np.zeros((h, w), bool)
    ex[1, 2] = True
    sig &= ~ex
    s0 = spot(0, sig, ~sig & ~ex, ex)
    s1 = spot(1, np.ones((h, w), bool), np.zeros((h, w), bool), np.zeros((h, w), bool))
    s1.path_length[0, 0] = np.nan                   # a 'signal' whose path is not finite
    return Measurements(width=w, height=h, fov_rad=1.0, fov_axis="x", camera_to_world=np.eye(4),
                        laser_origin=np.zeros(3), bin_width_m=0.04, shadow_threshold=0.15, spots=[s0, s1],
                        visible_depth=np.full((h, w), 2.0, np.float32))


def test_apply_intensity_shadows_label_logic():
    meas = _meas()
    rgb_sh = np.zeros((2, 2, 3), bool)
    rgb_sh[0, 0, 0] = True          # lidar lit -> shadow
    rgb_sh[0, 1, 2] = True          # excluded: stays excluded, not shadow
    out = apply_intensity_shadows(meas, rgb_sh)
    s0, s1 = out.spots
    assert s0.shadow[0, 0] and not s0.signal[0, 0] and np.isnan(s0.path_length[0, 0])
    assert not s0.shadow[1, 2] and not s0.signal[1, 2] and s0.excluded[1, 2]
    # lidar shadow at (0, 2), intensity lit: unlabelled (no path to fit, no shadow claim)
    assert not s0.shadow[0, 2] and not s0.signal[0, 2]
    assert s0.signal[0, 1] and s0.path_length[0, 1] == 4.0
    # spot 1: lit everywhere by intensity; the pixel without a finite lidar path is unlabelled
    assert not s1.shadow.any() and not s1.signal[0, 0] and s1.signal.sum() == 5
    assert np.isnan(out.spots[1].path_length[~s1.signal]).all()
    # the input is not modified, distances and visible depth are kept
    assert meas.spots[0].signal[0, 0] and not meas.spots[0].shadow[0, 0]
    assert out.visible_depth is meas.visible_depth and out.settings["shadow_source"] == "intensity"
    for bad in (np.zeros((2, 3, 2), bool), np.zeros((2, 2, 3), np.float32)):
        with pytest.raises(ValueError, match="shadow_masks"):
            apply_intensity_shadows(meas, bad)


def test_mask_agreement_counts():
    ref = np.array([[True, True, False, False]])
    lab = np.array([[True, True, True, False]])
    got = mask_agreement(np.array([[True, False, True, True]]), ref, lab)
    assert got["pixels"] == 3 and got["shadow_precision"] == 0.5 and got["shadow_recall"] == 0.5
    assert got["accuracy"] == pytest.approx(1 / 3)
    none = mask_agreement(np.zeros((1, 4), bool), np.zeros((1, 4), bool), lab)
    assert np.isnan(none["shadow_precision"]) and none["accuracy"] == 1.0


def test_rgb_png_luminance_round_trip(tmp_path):
    from skimage.io import imsave
    lin = np.array([[0.0, 0.002, 0.2, 1.0]])
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(srgb_to_linear(srgb), lin, atol=1e-9)
    imsave(tmp_path / "grey16.png", np.round(srgb * 65535).astype(np.uint16), check_contrast=False)
    np.testing.assert_allclose(read_rgb_luminance(tmp_path / "grey16.png"), lin, atol=2e-4)
    rgb8 = np.round(srgb * 255).astype(np.uint8)[..., None] * np.array([1, 1, 1], np.uint8)
    rgb8[0, 2] = (255, 0, 0)        # pure red: luminance 0.2126
    imsave(tmp_path / "rgb8.png", rgb8, check_contrast=False)
    got = read_rgb_luminance(tmp_path / "rgb8.png")
    np.testing.assert_allclose(got, [[0.0, 0.002, 0.2126, 1.0]], atol=5e-3)
    imsave(tmp_path / "f.tif", np.zeros((2, 2), np.float32), check_contrast=False)
    with pytest.raises(DatasetError, match=r"f\.tif: field 'rgb_files': expected an 8- or 16-bit PNG"):
        read_rgb_luminance(tmp_path / "f.tif")
    (tmp_path / "bad.png").write_text("not a png")
    with pytest.raises(DatasetError, match=r"bad\.png: field 'rgb_files': not a readable PNG"):
        read_rgb_luminance(tmp_path / "bad.png")
    with pytest.raises(FileNotFoundError):
        read_rgb_luminance(tmp_path / "none.png")
