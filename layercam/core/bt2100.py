"""HDR video signals (ITU-R BT.2100): the PQ and HLG transfer curves, BT.2020 primaries and
Y'CbCr, the BT.2390 highlight roll-off, in numpy.

* PQ (SMPTE ST 2084): absolute display light, 0..10000 cd/m2 <-> signal 0..1
  (:func:`pq_encode`, :func:`pq_decode`).
* HLG (ARIB STD-B67): relative scene light 0..1 <-> signal 0..1 (:func:`hlg_oetf`,
  :func:`hlg_inverse_oetf`); :func:`hlg_ootf` is what a display of peak ``Lw`` shows for it.
* :func:`primaries_matrix`: linear RGB of one set of primaries -> another (same D65 white), e.g.
  BT.709/sRGB -> BT.2020 (the BT.2087 matrix), from the chromaticities of :data:`PRIMARIES`.
* :func:`ycbcr_encode` / :func:`ycbcr_decode`: non-constant-luminance BT.2020 Y'CbCr, 10-bit narrow
  range ("tv") codes.
* :func:`eetf`: the BT.2390 EETF (a Hermite spline in the PQ domain) that rolls light above a knee
  off towards a display's peak, smoothly and monotonically.

>>> import numpy as np
>>> np.round(pq_encode(np.array([100.0, 1000.0, 10000.0])), 4).tolist()
[0.5081, 0.7518, 1.0]
>>> np.round(hlg_oetf(np.array([1 / 12, 1.0])), 4).tolist()
[0.5, 1.0]
>>> np.round(primaries_matrix("bt709", "bt2020")[0], 4).tolist()
[0.6274, 0.3293, 0.0433]
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "PRIMARIES", "primaries_matrix", "pq_encode", "pq_decode", "hlg_oetf", "hlg_inverse_oetf",
    "hlg_gamma", "hlg_ootf", "eetf", "ycbcr_encode", "ycbcr_decode", "LUMA_2020",
    "PQ_PEAK", "REFERENCE_WHITE", "DISPLAY_PEAK",
]  # fmt: skip

PQ_PEAK = 10000.0  # cd/m2 at PQ signal 1.0
REFERENCE_WHITE = 203.0  # cd/m2: BT.2408's HDR reference (diffuse) white, where SDR's 100% lands
DISPLAY_PEAK = 1000.0  # cd/m2: BT.2100/BT.2408's reference display for HLG, the usual HDR10 mastering peak

# CIE 1931 xy of the red, green and blue primaries; every set here has the D65 white point
D65 = (0.3127, 0.3290)
PRIMARIES: dict[str, tuple[tuple[float, float], ...]] = {
    "bt709": ((0.640, 0.330), (0.300, 0.600), (0.150, 0.060)),  # also sRGB
    "bt2020": ((0.708, 0.292), (0.170, 0.797), (0.131, 0.046)),
    "bt470bg": ((0.640, 0.330), (0.290, 0.600), (0.150, 0.060)),  # EBU / PAL
    "smpte170m": ((0.630, 0.340), (0.310, 0.595), (0.155, 0.070)),  # SMPTE C / NTSC
    "smpte432": ((0.680, 0.320), (0.265, 0.690), (0.150, 0.060)),  # Display P3
}
PRIMARIES["smpte240m"] = PRIMARIES["smpte170m"]
LUMA_2020 = (0.2627, 0.6780, 0.0593)  # BT.2020 luminance of linear RGB (Kr, Kg, Kb)

# SMPTE ST 2084
_M1, _M2 = 2610 / 16384, 2523 / 4096 * 128
_C1, _C2, _C3 = 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
# ARIB STD-B67 / BT.2100 HLG
_A = 0.17883277
_B = 1 - 4 * _A
_C = 0.5 - _A * np.log(4 * _A)


def _float(x) -> np.ndarray:
    """``x`` as a float array: float32 stays float32 (frames), anything else becomes float64."""
    x = np.asarray(x)
    return x if x.dtype in (np.float32, np.float64) else x.astype(np.float64)


def _rgb_to_xyz(prim) -> np.ndarray:
    """The 3x3 matrix from linear RGB of primaries ``prim`` (D65 white) to CIE XYZ (white Y = 1)."""
    xy = np.asarray(prim, np.float64)
    # XYZ of each primary at Y = 1
    cols = np.stack([xy[:, 0] / xy[:, 1], np.ones(3), (1 - xy[:, 0] - xy[:, 1]) / xy[:, 1]])
    w = np.array([D65[0] / D65[1], 1.0, (1 - D65[0] - D65[1]) / D65[1]])
    return cols * np.linalg.solve(cols, w)[None, :]


def primaries_matrix(src: str, dst: str = "bt2020") -> np.ndarray:
    """``(3, 3)`` float64 ``M``: linear RGB in primaries ``src`` -> ``dst`` (``rgb_dst = M @ rgb_src``;
    for ``(..., 3)`` images ``img @ M.T``). Both have the D65 white, so white stays white; each row
    sums to 1. Names as ffmpeg calls them (:data:`PRIMARIES`)."""
    for n in (src, dst):
        if n not in PRIMARIES:
            raise ValueError(f"unknown primaries {n!r} (one of {', '.join(PRIMARIES)})")
    return np.linalg.solve(_rgb_to_xyz(PRIMARIES[dst]), _rgb_to_xyz(PRIMARIES[src]))


def pq_encode(nits: np.ndarray) -> np.ndarray:
    """SMPTE ST 2084 inverse EOTF: display light in cd/m2 (``>= 0``, any shape; float32 stays
    float32, else float64) -> PQ signal in [0, 1] (10000 cd/m2 -> 1). Negative light is taken as 0.
    The formula goes on past 10000
    (towards 1.99 at infinity), monotone: :func:`eetf` places a source peak above PQ's with it."""
    y = np.maximum(_float(nits), 0.0) / PQ_PEAK
    p = y**_M1
    return ((_C1 + _C2 * p) / (1 + _C3 * p)) ** _M2


def pq_decode(signal: np.ndarray) -> np.ndarray:
    """SMPTE ST 2084 EOTF: PQ signal in [0, 1] (clipped there) -> display light in cd/m2."""
    e = np.clip(np.asarray(signal, np.float64), 0.0, 1.0) ** (1 / _M2)
    return PQ_PEAK * (np.maximum(e - _C1, 0.0) / (_C2 - _C3 * e)) ** (1 / _M1)


def hlg_oetf(e: np.ndarray) -> np.ndarray:
    """ARIB STD-B67 / BT.2100 HLG OETF: relative scene light ``E`` in [0, 1] (clipped there) ->
    signal ``E'`` in [0, 1]: ``sqrt(3 E)`` up to ``E = 1/12`` (signal 0.5), ``a ln(12 E - b) + c``
    above (``E = 1`` -> 1)."""
    e = np.clip(_float(e), 0.0, 1.0)
    return np.where(e <= 1 / 12, np.sqrt(3 * e), _A * np.log(np.maximum(12 * e - _B, 1e-12)) + _C).astype(e.dtype)


def hlg_inverse_oetf(signal: np.ndarray) -> np.ndarray:
    """The inverse of :func:`hlg_oetf`: signal in [0, 1] (clipped there) -> scene light in [0, 1]."""
    s = np.clip(np.asarray(signal, np.float64), 0.0, 1.0)
    return np.where(s <= 0.5, s * s / 3, (np.exp((s - _C) / _A) + _B) / 12)


def hlg_gamma(peak: float = DISPLAY_PEAK) -> float:
    """The HLG system gamma of a display of ``peak`` cd/m2 (BT.2100: 1.2 at 1000)."""
    return 1.2 + 0.42 * np.log10(peak / 1000.0)


def hlg_ootf(e: np.ndarray, peak: float = DISPLAY_PEAK) -> np.ndarray:
    """BT.2100 HLG OOTF (black level 0): scene light ``E (..., 3)`` (BT.2020 RGB in [0, 1]) -> the
    display light in cd/m2 that a display of ``peak`` shows, ``peak * Ys^(gamma - 1) * E``."""
    e = np.asarray(e, np.float64)
    ys = np.maximum(e @ np.asarray(LUMA_2020), 0.0)[..., None]
    return peak * np.power(np.maximum(ys, 1e-12), hlg_gamma(peak) - 1) * e


def eetf_knee(source_peak: float, target_peak: float = DISPLAY_PEAK) -> float:
    """The light in cd/m2 below which :func:`eetf` is the identity (``inf`` when the source fits)."""
    source_peak = min(float(source_peak), PQ_PEAK)
    if not source_peak > target_peak:
        return float("inf")
    src = float(pq_encode(source_peak))
    return float(pq_decode((1.5 * float(pq_encode(target_peak)) / src - 0.5) * src))


def eetf(nits: np.ndarray, source_peak: float, target_peak: float = DISPLAY_PEAK) -> np.ndarray:
    """The BT.2390 EETF (ITU-R BT.2390, section 5.4.1; black levels 0): light in cd/m2 from a source
    whose brightest value is ``source_peak`` -> light within ``target_peak``. In the PQ domain,
    normalised by the source peak's PQ value, signals below the knee ``KS = 1.5 maxLum - 0.5``
    (``maxLum``: the target peak's normalised PQ) pass unchanged; above it a Hermite spline meets
    the target peak at the source peak with slope 0, so the roll-off is continuous in value and
    slope and monotone: nothing is clipped or wraps. Identity when ``source_peak <= target_peak``.
    Values above ``source_peak`` are taken as the source peak, and a source peak above PQ's
    10000 cd/m2 as 10000 (light above it reaches the target peak): so the knee stays at or above
    340 cd/m2 for a 1000 cd/m2 target, above :data:`REFERENCE_WHITE`."""
    x = np.maximum(np.asarray(nits, np.float64), 0.0)
    source_peak = min(float(source_peak), PQ_PEAK)
    if not source_peak > target_peak:
        return x
    src = float(pq_encode(source_peak))
    e1 = np.minimum(pq_encode(x) / src, 1.0)
    max_lum = float(pq_encode(target_peak)) / src
    ks = 1.5 * max_lum - 0.5
    t = (e1 - ks) / (1 - ks)
    spline = (2 * t**3 - 3 * t**2 + 1) * ks + (t**3 - 2 * t**2 + t) * (1 - ks) + (-2 * t**3 + 3 * t**2) * max_lum
    e2 = np.where(e1 < ks, e1, spline)
    return np.where(e1 < ks, x, np.minimum(pq_decode(e2 * src), target_peak))


def ycbcr_encode(rgb: np.ndarray, rounded: bool = True) -> np.ndarray:
    """Non-linear BT.2020 R'G'B' in [0, 1] ``(..., 3)`` -> 10-bit narrow-range Y'CbCr codes
    ``(..., 3)`` uint16 (Y' 64..940, Cb/Cr 64..960, non-constant luminance); float64 codes, not
    rounded, with ``rounded=False`` (to subsample the chroma before rounding)."""
    rgb = np.clip(_float(rgb), 0.0, 1.0)
    kr, kg, kb = LUMA_2020
    y = rgb @ np.array([kr, kg, kb], rgb.dtype)
    cb = (rgb[..., 2] - y) / (2 * (1 - kb))
    cr = (rgb[..., 0] - y) / (2 * (1 - kr))
    out = np.stack([64 + 876 * y, 512 + 896 * cb, 512 + 896 * cr], -1)
    return np.clip(np.round(out), 0, 1023).astype(np.uint16) if rounded else out


def ycbcr_decode(codes: np.ndarray) -> np.ndarray:
    """The inverse of :func:`ycbcr_encode`: 10-bit narrow-range Y'CbCr ``(..., 3)`` -> R'G'B'
    ``(..., 3)`` float64, clipped to [0, 1]."""
    c = np.asarray(codes, np.float64)
    y, cb, cr = (c[..., 0] - 64) / 876, (c[..., 1] - 512) / 896, (c[..., 2] - 512) / 896
    kr, kg, kb = LUMA_2020
    r = y + 2 * (1 - kr) * cr
    b = y + 2 * (1 - kb) * cb
    g = (y - kr * r - kb * b) / kg
    return np.clip(np.stack([r, g, b], -1), 0.0, 1.0)
