"""The exposure difference between frames, measured from their pixels (a gamma-2.2 curve assumed,
what both frames see unclipped), and the check of a given ``--ev-step`` against it."""

from __future__ import annotations

import numpy as np

from layercam.core.errors import LayercamError

_GAMMA = 2.2  # the camera curve assumed when an EV is read from 8-bit values
_LO, _HI = 0.02, 0.95  # encoded-value range considered neither noise-dominated nor clipped


def _luma_small(frame: np.ndarray, max_side: int = 160) -> np.ndarray:
    h, w = frame.shape[:2]
    s = max(1, int(np.ceil(max(h, w) / max_side)))
    return frame[::s, ::s].mean(axis=2, dtype=np.float32)


def measure_pair_ev(a: np.ndarray, b: np.ndarray) -> float:
    """Rough EV of frame ``b`` relative to frame ``a`` (both ``(H,W,3)`` in [0,1]).

    Median over pixels unclipped in both of ``gamma*log2(b/a)``; when fewer than 0.5% of the
    pixels qualify (e.g. many stops apart), falls back to the difference of per-frame medians.
    """
    la, lb = _luma_small(a), _luma_small(b)
    ok = _both_unclipped(la, lb)
    if _enough(ok):
        return float(_GAMMA * np.median(np.log2(lb[ok]) - np.log2(la[ok])))

    def level(x: np.ndarray) -> float:
        good = (x > _LO) & (x < _HI)
        v = x[good] if np.any(good) else np.clip(x, 1e-3, 1.0)
        return float(np.median(np.log2(np.maximum(v, 1e-3))))

    return _GAMMA * (level(lb) - level(la))


def _both_unclipped(la: np.ndarray, lb: np.ndarray) -> np.ndarray:
    return (la > _LO) & (la < _HI) & (lb > _LO) & (lb < _HI)


def _enough(ok: np.ndarray) -> bool:
    """Enough pixels unclipped in both frames of a pair for a per-pixel measurement."""
    return np.count_nonzero(ok) >= max(16, 0.005 * ok.size)


def _pairs_measured_per_pixel(frames: np.ndarray) -> float:
    """Fraction of neighbouring pairs whose EV was measured per pixel (not from medians)."""
    lum = [_luma_small(f) for f in frames]
    return float(np.mean([_enough(_both_unclipped(a, b)) for a, b in zip(lum[:-1], lum[1:])])) if len(lum) > 1 else 0.0


# --ev-step against what the frames show: the measurement assumes a gamma-2.2 camera curve, so a
# camera curve of gamma g reads as 2.2 / g times its true ratio; within a factor of 2 (gamma 1.1 to
# 4.4) a given step is plausible. More than EV_WARN away is said; more than EV_WARN and a factor of
# 2 away, where the frames were measured per pixel, is refused (unless forced).
EV_WARN = 2.0


def check_ev_step(step: float, measured: np.ndarray, per_pixel: bool, force: bool) -> str:
    """A warning ("" when none) for ``--ev-step step`` against the measured gaps between the
    brightness-ordered phases; raises ``LayercamError`` when the frames contradict it."""
    far = [float(g) for g in measured if abs(step - g) > EV_WARN]
    if not far:
        return ""
    g = max(far, key=lambda v: abs(step - v))
    said = (f"--ev-step {step:g}, but the frames measure {g:.1f} EV between neighbouring exposures "
            "(assuming a gamma-2.2 camera curve)")
    contradicts = per_pixel and not (g / 2 <= step <= 2 * g)
    if contradicts and not force:
        raise LayercamError(f"{said}: more than {EV_WARN:g} EV and a factor of 2 apart, the HDR "
                            "would be wrong; leave --ev-step out to learn the ratio, or give "
                            "--force-ev-step to use it anyway")
    return f"{said}; using {step:g} (leave --ev-step out to learn the ratio)"


def _pair_diffs(frames: np.ndarray) -> np.ndarray:
    return np.array([measure_pair_ev(frames[t], frames[t + 1]) for t in range(len(frames) - 1)])


def _measure_phase_ev(frames: np.ndarray, phase: np.ndarray, n: int) -> tuple[np.ndarray, float]:
    """Least-squares EV per phase (phase 0 at 0) from medians of consecutive-pair EVs, and how far
    the pairs stray from their phase pair's median (EV, the mean over pairs: a cycle that fits most
    pairs but not every one strays too): near 0 where the frames do repeat every ``n`` exposures, a
    good part of the step between exposures where they do not."""
    d = _pair_diffs(frames)
    rows, rhs = [], []
    groups: dict[tuple[int, int], list[float]] = {}
    for t, v in enumerate(d):
        a, b = int(phase[t]), int(phase[t + 1])
        if a == b:
            continue
        groups.setdefault((a, b), []).append(float(v))
    for (a, b), vals in groups.items():
        row = np.zeros(n)
        row[b] += 1.0
        row[a] -= 1.0
        rows.append(row)
        rhs.append(float(np.median(vals)))
    row0 = np.zeros(n)
    row0[0] = 1.0
    rows.append(row0 * 10.0)
    rhs.append(0.0)
    sol, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    stray = [abs(v - np.median(vals)) for vals in groups.values() for v in vals]
    return sol, float(np.nanmean(stray)) if stray else 0.0
