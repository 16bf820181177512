"""Deterministic synthetic scenes rendered through a known camera, with ground truth.

Every family draws all its randomness from ``numpy.random.default_rng(seed)``, so the same
arguments give bit-identical frames. The imaging model is

    irradiance E (linear, HDR)  ->  E * t * gain  ->  clip [0,1]  ->  CRF  ->  + N(0, noise)
    ->  clip [0,1]  ->  8-bit quantisation

where ``t`` is the exposure time (``SynthScene.exposure_times``, relative seconds) and ``gain``
(``meta["gain"]``) a constant of the scene. The noise is added after the CRF, in the LDR
domain, so that ``noise`` is in units of output intensity. ``SynthScene.hdr`` is ``E`` itself,
i.e. a tool that recovers irradiance is right up to one scale per channel.

Families (``FAMILIES``, dispatch with ``make``):

* ``pan_hdr``: a camera pans and zooms across an HDR canvas, alternating exposures.
* ``static_single``: a static camera, one exposure, sharp frames.
* ``moving_object``: ``pan_hdr`` plus an independently moving textured blob (``fg_mask``).
* ``shake_blur``: camera-shake motion blur (integrated in linear irradiance), ``sharp_ldr``.
* ``mfme_stack``: a static multi-focus multi-exposure stack of depth planes, ``allfocus_hdr``.

Geometry: for families with a camera path, ``meta["frame_affine"]`` is ``(T,2,3)``, mapping a
frame pixel ``(x, y, 1)`` (pixel centres at integers, OpenCV convention) to canvas coordinates;
``true_flow(scene)`` turns it (and the object's ``meta["object_affine"]``) into ground-truth
forward optical flow.
"""

from __future__ import annotations

from layercam.core.errors import LayercamError
from layercam.synth.camera import CRFS, SynthScene, crf_apply, crf_inverse
from layercam.synth.canvas import hdr_canvas
from layercam.synth.shake import shake_blur
from layercam.synth.stack import mfme_stack
from layercam.synth.video import moving_object, pan_hdr, pan_hdr_frames, static_single, true_flow

__all__ = [
    "CRFS",
    "FAMILIES",
    "SynthScene",
    "crf_apply",
    "crf_inverse",
    "hdr_canvas",
    "make",
    "mfme_stack",
    "moving_object",
    "pan_hdr",
    "pan_hdr_frames",
    "shake_blur",
    "static_single",
    "true_flow",
]


FAMILIES = ["pan_hdr", "static_single", "moving_object", "shake_blur", "mfme_stack"]

_FAMILY_FUNCS = {
    "pan_hdr": pan_hdr,
    "static_single": static_single,
    "moving_object": moving_object,
    "shake_blur": shake_blur,
    "mfme_stack": mfme_stack,
}


def make(family: str, **kw) -> SynthScene:
    """Render the named family (``FAMILIES``) with keyword arguments passed through."""
    if family not in _FAMILY_FUNCS:
        raise LayercamError(
            f"unknown synthetic family {family!r}; choose one of {', '.join(FAMILIES)}"
        )
    import inspect

    fn = _FAMILY_FUNCS[family]
    bad = sorted(set(kw) - set(inspect.signature(fn).parameters))
    if bad:
        raise LayercamError(f"synthetic family {family!r} has no parameter(s) {', '.join(bad)}")
    return fn(**kw)
