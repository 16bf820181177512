"""What a user would otherwise run: OpenCV's merges on the same shots with their times.

* :func:`bracket_merges`: ``CalibrateDebevec`` + ``MergeDebevec`` and ``CalibrateRobertson`` +
  ``MergeRobertson`` (OpenCV's defaults) on the shots as given, unaligned, and ``MergeMertens``
  (display-referred exposure fusion: for the figures only, it has no radiance to score).
* :func:`robertson_reference`: the Robertson merge of ALL shots of a bracket, the reference the
  3-shot subsets are scored against when no ground truth exists (and the composites' background).
* video: ``layercam.bench.baselines.debevec_video`` (each frame merged with its DIS-aligned neighbour).
* deblurring (:func:`deblur_baselines`): unsharp masking and flow-aligned lucky regions
  (``layercam.bench.baselines``), and the blurry input itself, the floor every method must clear.

Images are float RGB in [0,1] ``(N,H,W,3)`` as ``layercam.io.load_clip`` gives them (what layercam
sees); OpenCV gets their 8-bit codes. Outputs are linear float32 on OpenCV's own scale.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["bracket_merges", "deblur_baselines", "robertson_reference", "video_merge"]


def _u8(frames: np.ndarray) -> list[np.ndarray]:
    return [np.ascontiguousarray(np.round(np.clip(f, 0, 1) * 255).astype(np.uint8)) for f in frames]


def _finite(hdr: np.ndarray) -> np.ndarray:
    hdr = np.asarray(hdr, np.float32)
    bad = ~np.isfinite(hdr)
    if bad.any():
        hdr[bad] = float(hdr[~bad].max()) if (~bad).any() else 0.0
    return np.maximum(hdr, 0.0)


def robertson_reference(frames: np.ndarray, times: np.ndarray) -> np.ndarray:
    """OpenCV ``CalibrateRobertson`` + ``MergeRobertson`` of all ``(N,H,W,3)`` shots with their
    times ``(N,)`` in seconds -> ``(H,W,3)`` float32 radiance."""
    import cv2

    u8 = _u8(frames)
    t = np.asarray(times, np.float32)
    resp = cv2.createCalibrateRobertson().process(u8, t)
    return _finite(cv2.createMergeRobertson().process(u8, t, resp))


def bracket_merges(frames: np.ndarray, times: np.ndarray) -> dict:
    """The classical merges of a bracket ``(N,H,W,3)`` with times ``(N,)``: ``{"debevec": {"hdr",
    "seconds"}, "robertson": {...}, "mertens": {"ldr", "seconds"}}`` (hdr ``(H,W,3)`` linear,
    ldr in [0,1])."""
    import cv2

    u8 = _u8(frames)
    t = np.asarray(times, np.float32)
    out = {}
    for name, cal, merge in (("debevec", cv2.createCalibrateDebevec, cv2.createMergeDebevec),
                             ("robertson", cv2.createCalibrateRobertson, cv2.createMergeRobertson)):
        t0 = time.perf_counter()
        hdr = merge().process(u8, t, cal().process(u8, t))
        out[name] = {"hdr": _finite(hdr), "seconds": time.perf_counter() - t0}
    t0 = time.perf_counter()
    ldr = cv2.createMergeMertens().process(u8)
    out["mertens"] = {"ldr": np.clip(np.asarray(ldr, np.float32), 0, 1), "seconds": time.perf_counter() - t0}
    return out


def video_merge(frames: np.ndarray, times: np.ndarray) -> dict:
    """Flow + Debevec on a clip ``(T,H,W,3)`` with times ``(T,)``: DIS flow (``dis_medium``, as the
    synthetic benchmark), then ``layercam.bench.baselines.debevec_video``. ``{"hdr": (T,H,W,3),
    "seconds"}``; the seconds include the flow."""
    from layercam.bench import baselines
    from layercam.vision import flow

    t0 = time.perf_counter()
    fw, bw = flow.compute_flow(frames, method="dis_medium", progress=False)
    hdr = baselines.debevec_video(frames, times, fw, bw)
    return {"hdr": _finite(hdr), "seconds": time.perf_counter() - t0}


def deblur_baselines(frames: np.ndarray) -> dict:
    """What a user could run on a blurry clip ``(T,H,W,3)`` in [0,1]: ``{"input": ..., "unsharp":
    ..., "lucky": ...}``, each ``{"ldr": (T,H,W,3) in [0,1], "seconds"}``: the input as it is,
    ``layercam.bench.baselines.unsharp_mask`` (sigma 1.5 px, amount 1) and
    ``layercam.bench.baselines.lucky_regions`` (neighbours 2 frames either side, DIS flow included)."""
    from layercam.bench import baselines

    out = {"input": {"ldr": np.asarray(frames, np.float32), "seconds": 0.0}}
    for name, fn in (("unsharp", baselines.unsharp_mask), ("lucky", baselines.lucky_regions)):
        t0 = time.perf_counter()
        out[name] = {"ldr": fn(frames), "seconds": time.perf_counter() - t0}
    return out
