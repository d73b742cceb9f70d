"""Modality presets: fixed value ranges, transfer-function presets in physical units, the range hint."""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.volume.modality import (
    HINT_FRACTION,
    MODALITY_RANGES,
    TF_PRESETS,
    UNSUPPORTED,
    modality_range,
    range_hint,
    tf_preset,
    window_density,
)

CT = (-1024.0, 3071.0)


def test_ct_is_the_12_bit_hounsfield_range():
    assert modality_range("CT") == CT == modality_range(" ct")
    lo, hi = CT
    assert hi - lo + 1 == 4096  # 12 bits
    # air, water and bone land where a reader expects them
    assert hevr.normalize_density(np.array([-1000, 0, 1000], np.int16), CT).round(3).tolist() == [0.006, 0.25, 0.494]


@pytest.mark.parametrize("code", sorted(MODALITY_RANGES))
def test_every_range_is_a_valid_value_range(code):
    lo, hi = modality_range(code)
    assert hi > lo and all(isinstance(v, float) for v in (lo, hi))


@pytest.mark.parametrize("code", sorted(UNSUPPORTED))
def test_modalities_without_a_scale_are_refused_with_the_reason(code):
    with pytest.raises(
        hevr.ParameterError, match=rf"^modality: {code} has no fixed value range \(.+\); give a value_range"
    ):
        modality_range(code)


@pytest.mark.parametrize("bad", ["XX", "", None, 3])
def test_unknown_modality(bad):
    with pytest.raises(hevr.ParameterError, match="^modality: expected"):
        modality_range(bad)


def test_window_density_clips_to_unit_interval():
    assert window_density(-600, 1500, CT) == (0.0, round((150 + 1024) / 4095, 4))
    assert window_density(3000, 1000, CT)[1] == 1.0
    with pytest.raises(hevr.ParameterError, match="^width:"):
        window_density(0, 0, CT)
    with pytest.raises(hevr.ParameterError, match="^value_range:"):
        window_density(0, 10, (5, 1))


@pytest.mark.parametrize("name", sorted(TF_PRESETS))
def test_presets_are_valid_render_nodes(name):
    preset = TF_PRESETS[name]
    vr = modality_range(preset.modality)
    nodes = tf_preset(name, vr)
    assert len(nodes) == len(preset.nodes)  # every node lies inside its modality's range
    dens = [d for d, _ in nodes]
    assert dens == sorted(set(dens)) and all(0 <= d <= 1 for d in dens)
    assert all(len(c) == 3 and all(0 <= x <= 1 for x in c) for _, c in nodes)
    # nodes lie inside the preset's window
    lo, hi = (preset.center - preset.width / 2, preset.center + preset.width / 2)
    assert all(lo <= v <= hi for v, _ in preset.nodes)
    # hevr.render_plain accepts them
    vol = np.linspace(vr[0], vr[1], 64).reshape(4, 4, 4)
    img = hevr.render_plain(
        vol, hevr.Camera.orbit(vol.shape, width=3, height=3), mode="tf", nodes=nodes, vector_dims=4, value_range=vr
    )
    assert img.shape == (3, 3, 3) and img.max() > 0


def test_ct_bone_highlights_bone_more_than_soft_tissue():
    nodes = tf_preset("ct-bone", CT)
    assert nodes[0][0] == round((300 + 1024) / 4095, 4)
    cam = hevr.Camera.orbit((4, 4, 4), width=2, height=2, parallel=True)

    def tf(hu, dims):
        return hevr.render_plain(
            np.full((4, 4, 4), hu, np.int16), cam, mode="tf", nodes=nodes, vector_dims=dims, value_range=CT
        ).sum()

    assert tf(900, 16) > 2 * tf(40, 16)  # the encoding's bumps are wide at few dimensions
    assert tf(900, 32) > 0 and tf(40, 32) == 0 and tf(-1000, 32) == 0  # and selective at more


def test_presets_follow_the_value_range():
    # the same Hounsfield value -> another density when the store's range differs
    wide = tf_preset("ct-bone", (-2048, 4095))
    assert wide[0][0] == round((300 + 2048) / 6143, 4)
    # nodes outside the range are left out; none inside is refused
    assert [d for d, _ in tf_preset("ct-bone", (-1024, 1000))] == [round(1324 / 2024, 4), round(1724 / 2024, 4)]
    with pytest.raises(
        hevr.ParameterError, match=r"^name: the CT preset 'ct-bone' has no node inside the value range \(0, 255\)"
    ):
        tf_preset("ct-bone", (0, 255))
    # MR presets are relative: the same densities for every range
    assert tf_preset("mr-generic", (0, 4095)) == tf_preset("mr-generic", (0, 255))
    with pytest.raises(hevr.ParameterError, match="^name: expected a transfer-function preset"):
        tf_preset("ct-brain", CT)


def test_range_hint():
    int16 = (-32768.0, 32767.0)
    msg = range_hint(0, 1500, int16)
    assert msg is not None and "nearly flat" in msg and "--modality" in msg and "--value-range" in msg
    assert "\n" not in msg
    assert range_hint(-1024, 3000, CT) is None
    assert range_hint(-3024, 3000, CT) is None  # padding below the range is fine
    assert range_hint(0, 255, (0, 255)) is None
    # just above / below the threshold
    span = int16[1] - int16[0]
    assert range_hint(0, span * (HINT_FRACTION + 0.01), int16) is None
    assert range_hint(0, span * (HINT_FRACTION - 0.01), int16) is not None
    over = range_hint(0, 20000, (0, 4095))
    assert over is not None and "above the value range" in over and "density 1" in over
    assert range_hint(7, 7, (0, 4095)) is not None  # a constant volume is flat
    assert range_hint(float("nan"), 1, CT) is None
