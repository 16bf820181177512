"""A set of linear HDR images written as OpenEXR one at a time, all of one pixel type."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError


HALF_MAX = 65504.0  # the largest half float


class HdrSet:
    """Linear HDR images written as EXR one at a time, all of one type: half floats unless an image
    exceeds what they hold (65504), after which the whole set is float32 (the images written
    before are rewritten; their values were half floats already). Refuses (one line) an image
    that is not finite, before writing it. ``lo``/``hi``: the set's extremes so far."""

    def __init__(self, half: bool, say=None):
        self.half, self.say = bool(half), say
        self.paths: list[Path] = []
        self.lo, self.hi = float("inf"), float("-inf")

    def add(self, path: Path, img: np.ndarray) -> None:
        from layercam.io import read_exr, write_exr

        if not np.isfinite(img).all():
            raise LayercamError(f"{path.name}: the model rendered non-finite irradiance; not writing it")
        peak = float(img.max())
        if self.half and peak > HALF_MAX:
            if self.say:
                self.say(f"[export] irradiance reaches {peak:.3g}, beyond half floats: EXRs written as float32")
            for p in self.paths:
                write_exr(p, read_exr(p), half=False)
            self.half = False
        write_exr(path, img, half=self.half)
        self.paths.append(path)
        self.lo, self.hi = min(self.lo, float(img.min())), max(self.hi, peak)


def write_hdr_set(paths: list[Path], images, half: bool, say=None) -> bool:
    """Write linear HDR images (any iterable) as EXR, all of one type (:class:`HdrSet`).
    Returns whether half floats were used."""
    hs = HdrSet(half, say)
    for p, img in zip(paths, images):
        hs.add(p, img)
    return hs.half
