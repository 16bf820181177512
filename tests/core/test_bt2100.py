"""layercam.core.bt2100 against the standards' reference values (SMPTE ST 2084, ARIB STD-B67 / ITU-R
BT.2100, BT.2087, BT.2390, BT.2408)."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.core import bt2100 as b


@pytest.mark.parametrize("nits, signal",
                         [(0.0, 0.0), (0.1, 0.0623), (1.0, 0.1499), (100.0, 0.5081),
                          (203.0, 0.5807), (1000.0, 0.7518), (4000.0, 0.9026), (10000.0, 1.0)])
def test_pq_reference_values(nits, signal):
    # ST 2084 / BT.2408 table: 100 cd/m2 -> 0.508, 203 (reference white) -> 0.58, 1000 -> 0.752, 10000 -> 1
    assert b.pq_encode(np.array(nits)) == pytest.approx(signal, abs=6e-5)
    assert b.pq_decode(np.array(signal)) == pytest.approx(nits, rel=1e-3, abs=1e-3)


def test_pq_round_trip_and_monotone():
    x = np.geomspace(1e-4, 1e4, 2001)
    e = b.pq_encode(x)
    assert np.all(np.diff(e) > 0)
    np.testing.assert_allclose(b.pq_decode(e), x, rtol=1e-9)


@pytest.mark.parametrize("scene, signal", [(0.0, 0.0), (1 / 12, 0.5), (1.0, 1.0)])
def test_hlg_oetf_reference_values(scene, signal):
    assert b.hlg_oetf(np.array(scene)) == pytest.approx(signal, abs=1e-6)
    assert b.hlg_inverse_oetf(np.array(signal)) == pytest.approx(scene, abs=1e-7)


def test_hlg_round_trip_is_continuous_at_the_knee():
    e = np.linspace(0, 1, 100001)
    s = b.hlg_oetf(e)
    assert np.all(np.diff(s) > 0)
    k = np.array([1 / 12 - 1e-9, 1 / 12 + 1e-9])
    assert np.diff(b.hlg_oetf(k))[0] == pytest.approx(0.0, abs=1e-7)  # no jump where the square root meets the log
    np.testing.assert_allclose(b.hlg_inverse_oetf(s), e, atol=1e-9)


def test_hlg_reference_white_is_75_percent_on_a_1000_nit_display():
    # BT.2408: HDR reference white (203 cd/m2) at 75% HLG signal on the 1000 cd/m2 reference display
    e = (203.0 / 1000.0) ** (1 / b.hlg_gamma(1000.0))
    assert b.hlg_oetf(np.array(e)) == pytest.approx(0.75, abs=2e-3)
    assert b.hlg_ootf(np.full((1, 3), e))[0] == pytest.approx([203.0] * 3, rel=1e-9)
    assert b.hlg_gamma(1000.0) == pytest.approx(1.2)


def test_bt709_to_bt2020_is_the_bt2087_matrix():
    m = b.primaries_matrix("bt709", "bt2020")
    bt2087 = [[0.6274, 0.3293, 0.0433], [0.0691, 0.9195, 0.0114], [0.0164, 0.0880, 0.8956]]
    np.testing.assert_allclose(m, bt2087, atol=1e-4)
    np.testing.assert_allclose(m.sum(1), 1.0, atol=1e-12)  # white stays white
    np.testing.assert_allclose(b.primaries_matrix("bt2020", "bt709") @ m, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(b.primaries_matrix("bt2020", "bt2020"), np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="unknown primaries"):
        b.primaries_matrix("adobe", "bt2020")


def test_eetf_rolls_off_smoothly_and_never_past_the_target():
    x = np.linspace(0, 4000, 400001)
    y = b.eetf(x, 4000.0, 1000.0)
    knee = x[np.argmax(y < x - 1e-9)]
    assert 300 < knee < 1000
    np.testing.assert_allclose(y[x < knee], x[x < knee])  # identity below the knee
    assert np.all(np.diff(y) >= 0)  # monotone: nothing wraps
    slope = np.diff(y) / np.diff(x)
    assert np.max(np.abs(np.diff(slope))) < 1e-3  # continuous slope: no corner at the knee
    assert y.max() <= 1000.0 and y[-1] == pytest.approx(1000.0, abs=1e-6) and y[x == 3000.0][0] < 999.0
    np.testing.assert_allclose(b.eetf(x, 900.0, 1000.0), x)  # a source within the target: untouched
    assert b.eetf(np.array([1e6]), 1e6, 1000.0) == pytest.approx(1000.0)  # beyond PQ's 10000: to the peak, not black
    assert b.eetf(np.array([203.0]), 1e6, 1000.0) == pytest.approx(203.0)  # the knee stays above reference white


def test_ycbcr_10bit_narrow_range_round_trip():
    rgb = np.random.default_rng(0).random((1000, 3))
    codes = b.ycbcr_encode(rgb)
    assert codes.dtype == np.uint16 and codes[..., 0].min() >= 64 and codes[..., 0].max() <= 940
    assert b.ycbcr_encode(np.ones(3)).tolist() == [940, 512, 512]  # white: Y' 940, no chroma
    assert b.ycbcr_encode(np.zeros(3)).tolist() == [64, 512, 512]
    np.testing.assert_allclose(b.ycbcr_decode(codes), rgb, atol=2e-3)


def test_eetf_knee_is_where_the_roll_off_starts():
    for src in (1500.0, 4000.0, 10000.0, 1e6):
        k = b.eetf_knee(src, 1000.0)
        assert 300 < k < 1000
        below, above = np.array([k * 0.999]), np.array([k * 1.01])
        assert b.eetf(below, src)[0] == pytest.approx(below[0], rel=1e-9) and b.eetf(above, src)[0] < above[0]
    assert b.eetf_knee(800.0, 1000.0) == float("inf")
    x = np.geomspace(1, 1e4, 100).astype(np.float32)  # frames stay float32
    assert b.pq_encode(x).dtype == np.float32 and b.hlg_oetf(x / 1e4).dtype == np.float32
    # a hundredth of a 10-bit code
    np.testing.assert_allclose(b.pq_encode(x), b.pq_encode(x.astype(np.float64)), atol=1e-5)
