"""Optical flow between frames of different exposures (OpenCV DIS; optional torchvision RAFT).

Conventions (OpenCV): a flow is ``(H,W,2)`` float32 in pixels, ``(dx, dy)`` order. The forward
flow ``fw[t]`` maps a pixel ``x`` of frame ``t`` to ``x + fw[t](x)`` in frame ``t+1``;
``bw[t]`` maps frame ``t+1`` back to frame ``t``. ``warp(frames[t+1], fw[t])`` therefore
resamples frame ``t+1`` into frame ``t``'s view (backward warping).

Frames of different exposures do not satisfy brightness constancy, so every frame goes
through ``normalise_for_flow`` (an exposure-invariant rank transform) before DIS.
"""

from __future__ import annotations


import numpy as np

from layercam.core.errors import LayercamError
from layercam.core.geometry import pixel_grid, warp  # noqa: F401 - warp: the flow's backward warp,
                                                     # imported from here too
from layercam.vision.flow_input import check_frame, check_frames, normalise_for_flow, pair_progress

__all__ = [
    "FLOW_METHODS",
    "compute_flow",
    "flow_consistency",
    "global_homographies",
    "pair_arrays",
    "residual_motion",
    "warp",
]

FLOW_METHODS = ("dis_ultrafast", "dis_fast", "dis_medium")
_DIS_FINEST_MIN = 128  # px on the short side of DIS's finest pyramid level (see _dis)
_DIS_MIN = 16  # OpenCV DIS needs frames of at least about 12 px; smaller ones are edge-padded


# --------------------------------------------------------------------------------------------
# Dense flow (DIS)
# --------------------------------------------------------------------------------------------


def _dis(method: str, shape: tuple[int, int]):
    import cv2

    preset = {
        "dis_ultrafast": cv2.DISOpticalFlow_PRESET_ULTRAFAST,
        "dis_fast": cv2.DISOpticalFlow_PRESET_FAST,
        "dis_medium": cv2.DISOpticalFlow_PRESET_MEDIUM,
    }[method]
    dis = cv2.DISOpticalFlow_create(preset)
    # The presets start at 1/4 (fast) or 1/2 (medium) resolution: on small frames an object a few
    # tens of pixels wide then vanishes and its flow is the background's (dis_fast on a 96x96 clip
    # measured 0.5 px on an object moving 4.8 px against the background; at full resolution 2.0).
    # Keep the finest level at least _DIS_FINEST_MIN px on the short side.
    fits = max(int(np.floor(np.log2(max(min(shape), 1) / _DIS_FINEST_MIN))), 0)
    dis.setFinestScale(min(dis.getFinestScale(), fits))
    return dis


def compute_flow(
    frames,
    method: str = "dis_medium",
    progress: bool = True,
    normaliser: str = "rank",
    weights_path: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward and backward flow between consecutive frames.

    frames: ``(T,H,W,3)`` float in [0,1]. method: one of ``FLOW_METHODS`` (OpenCV DIS
    presets), or "raft" / "raft_small" / "raft_large" with ``weights_path`` (see ``raft_flow``;
    "raft": the variant the file holds).
    Returns ``(fw, bw)``, each ``(T-1,H,W,2)`` float32 (``(0,H,W,2)`` when T == 1):
    ``fw[t]`` from frame t to t+1, ``bw[t]`` from t+1 to t.
    """
    f = check_frames(frames)
    t, h, w = f.shape[:3]
    if method in ("raft", "raft_small", "raft_large"):
        if not weights_path:
            raise LayercamError(f"flow method {method!r} needs a weights file (weights_path)")
        from layercam.vision.raft import raft_flow

        return raft_flow(f, weights_path, variant=method[5:] or None, progress=progress)
    if method not in FLOW_METHODS:
        raise LayercamError(
            f"unknown flow method {method!r}; choose one of {', '.join(FLOW_METHODS)}, "
            "raft, raft_small, raft_large"
        )
    fw = np.zeros((max(t - 1, 0), h, w, 2), np.float32)
    bw = np.zeros_like(fw)
    for i, (a,
            b) in enumerate(pair_progress(dis_pairs(iter(f), method, normaliser), t - 1, progress,
                                          f"flow ({method})")):
        fw[i], bw[i] = a, b
    return fw, bw


def dis_pairs(frames, method: str = "dis_medium", normaliser: str = "rank"):
    """Forward and backward DIS flow of each pair of consecutive frames of the iterable ``frames``
    (``(H,W,3)`` float in [0,1], read one at a time): yields ``(fw, bw)``, each ``(H,W,2)`` float32,
    for pairs 0, 1, ... (what :func:`compute_flow` stacks; a stage that keeps them on disk
    streams them)."""
    if method not in FLOW_METHODS:
        raise LayercamError(f"unknown flow method {method!r}; choose one of {', '.join(FLOW_METHODS)}")
    it = iter(frames)
    first = next(it, None)
    if first is None:
        return
    f0 = check_frame(first)
    h, w = f0.shape[:2]
    dis = _dis(method, (h, w))
    # DIS refuses frames smaller than its patches: edge-pad tiny frames to _DIS_MIN, crop the flow
    ph, pw = max(_DIS_MIN - h, 0), max(_DIS_MIN - w, 0)
    pad = lambda g: np.pad(g, ((0, ph), (0, pw)), mode="edge") if ph or pw else g  # noqa: E731
    prev = pad(normalise_for_flow(f0, normaliser))
    for frame in it:
        nxt = pad(normalise_for_flow(frame, normaliser))
        yield dis.calc(prev, nxt, None)[:h, :w], dis.calc(nxt, prev, None)[:h, :w]
        prev = nxt


# --------------------------------------------------------------------------------------------
# Warping and consistency
# --------------------------------------------------------------------------------------------


def _check_pair(fw, bw=None) -> tuple[np.ndarray, np.ndarray | None]:
    f = np.asarray(fw, dtype=np.float32)
    if f.ndim != 4 or f.shape[3] != 2:
        raise LayercamError(f"expected flows (T-1,H,W,2), got shape {f.shape}")
    if bw is None:
        return f, None
    b = np.asarray(bw, dtype=np.float32)
    if b.shape != f.shape:
        raise LayercamError(f"forward {f.shape} and backward {b.shape} flows differ in shape")
    return f, b


def flow_consistency(fw, bw, abs_tol: float = 1.0, rel_tol: float = 0.05) -> np.ndarray:
    """Forward-backward check ``(T-1,H,W)`` bool: True where
    ``|fw(x) + bw(x + fw(x))| < abs_tol + rel_tol*|fw(x)|`` and ``x + fw(x)`` is inside."""
    f, b = _check_pair(fw, bw)
    n, h, w = f.shape[:3]
    out = np.zeros((n, h, w), bool)
    xx, yy = pixel_grid(h, w)
    for i in range(n):
        bw_at = warp(b[i], f[i])
        err = np.linalg.norm(f[i] + bw_at, axis=-1)
        mag = np.linalg.norm(f[i], axis=-1)
        x1, y1 = xx + f[i][..., 0], yy + f[i][..., 1]
        inside = (x1 >= 0) & (x1 <= w - 1) & (y1 >= 0) & (y1 <= h - 1)
        out[i] = inside & (err < abs_tol + rel_tol * mag)
    return out


# --------------------------------------------------------------------------------------------
# Global (camera) motion and residual motion
# --------------------------------------------------------------------------------------------


SIMPLER_SHARE = 0.9  # see global_homographies


def global_homographies(fw, grid: int = 32, thresh: float = 1.0, seed: int = 0, mask=None,
                        min_points: int = 24) -> np.ndarray:
    """Per-pair homography ``(T-1,3,3)`` (frame t -> t+1 pixel coordinates), fitted with RANSAC
    (reprojection threshold ``thresh`` px) to ``grid x grid`` flow correspondences.

    ``mask (T-1,H,W)`` bool, optional: the pixels whose flow is evidence (e.g. consistent and seen
    well by both frames, :func:`layercam.core.visibility.pair_visible`); then the correspondences are
    those of a ``2 grid x 2 grid`` lattice inside the mask, and a pair with fewer than
    ``min_points`` inside gets the identity (no evidence of motion: the flow between the dark frames
    of a bracket is noise), one with fewer than ``8 min_points`` no homography (one fitted to a few
    clustered points extrapolates wildly to the corners; ``docs/measurements.md``).
    Of identity, median translation and homography, the simplest that explains (within
    ``thresh``) at least ``SIMPLER_SHARE`` as many points as the best is kept.
    """
    import cv2

    if np.ndim(fw) != 4 or np.shape(fw)[3] != 2:
        raise LayercamError(f"expected flows (T-1,H,W,2), got shape {np.shape(fw)}")
    n = np.shape(fw)[0]
    out = np.repeat(np.eye(3)[None], n, 0)
    cv2.setRNGSeed(seed)
    for i in range(n):  # a pair at a time (flows kept on disk are read pair by pair)
        out[i] = pair_homography(np.asarray(fw[i], np.float32),
                                 None if mask is None else np.asarray(mask[i]), grid, thresh,
                                 min_points)
    return out.astype(np.float64)


def pair_homography(f: np.ndarray, mask: np.ndarray | None = None, grid: int = 32,
                    thresh: float = 1.0, min_points: int = 24) -> np.ndarray:
    """One pair's homography ``(3,3)`` for :func:`global_homographies` (which seeds OpenCV's RNG
    once for all pairs: a caller fitting pairs as they come seeds it once too)."""
    import cv2

    h, w = f.shape[:2]
    lattice = []
    for g in (grid, 2 * grid):
        ys = np.linspace(0, h - 1, min(g, h)).round().astype(int)
        xs = np.linspace(0, w - 1, min(g, w)).round().astype(int)
        gy, gx = np.meshgrid(ys, xs, indexing="ij")
        lattice.append((gy.ravel(), gx.ravel()))
    gy, gx = lattice[0]
    if mask is not None:
        my, mx = lattice[1]
        keep = np.asarray(mask)[my, mx]
        if keep.sum() < min_points:
            return np.eye(3)  # identity
        gy, gx = my[keep], mx[keep]
    src = np.stack([gx, gy], -1).astype(np.float32)
    d = f[gy, gx]
    hm = None
    if mask is not None and len(src) < 8 * min_points:
        pass  # too few points to pin a homography down: identity or translation below
    elif len(src) >= 4:
        hm, _ = cv2.findHomography(src, src + d, cv2.RANSAC, thresh, maxIters=2000,
                                   confidence=0.995)
    shift = np.median(d, axis=0)
    # the simplest model that explains nearly as many points (Occam): identity, translation,
    # homography (RANSAC fits a zoom to the flow noise between two differently focused images)
    explained = {"identity": int((np.linalg.norm(d, axis=1) < thresh).sum()),
                 "translation": int((np.linalg.norm(d - shift, axis=1) < thresh).sum())}
    if hm is not None and np.all(np.isfinite(hm)):
        pts = np.concatenate([src, np.ones((len(src), 1), np.float32)], 1) @ hm.T
        explained["homography"] = int((np.linalg.norm(pts[:, :2] / pts[:, 2:] - (src + d), axis=1) < thresh).sum())
    best = max(explained.values())
    kind = next(k for k in ("identity", "translation", "homography")
                if k in explained
                and explained[k] >= SIMPLER_SHARE * best) if best else "translation"
    if kind != "homography":
        hm = np.eye(3)
        if kind == "translation":
            hm[:2, 2] = shift
    return hm / hm[2, 2]


def pair_arrays(frames, fw, bw) -> dict:
    """What the flow stage keeps besides the flows themselves: ``fw_ok``/``bw_ok`` (forward-backward
    consistency), ``vis`` (``(T-1,H,W)``: both frames see the pixel well,
    :func:`layercam.core.visibility.pair_visible`) and ``homs``, the per-pair homographies fitted where
    the flow is consistent and both frames see well."""
    from layercam.core.visibility import pair_visible

    fw_ok = flow_consistency(fw, bw)
    vis = pair_visible(frames, fw)
    return {"fw_ok": fw_ok, "bw_ok": flow_consistency(bw, fw), "vis": vis,
            "homs": global_homographies(fw, mask=vis & fw_ok)}


def _homography_flow(hm: np.ndarray, h: int, w: int) -> np.ndarray:
    xx, yy = pixel_grid(h, w)
    x = hm[0, 0] * xx + hm[0, 1] * yy + hm[0, 2]
    y = hm[1, 0] * xx + hm[1, 1] * yy + hm[1, 2]
    z = hm[2, 0] * xx + hm[2, 1] * yy + hm[2, 2]
    z = np.where(np.abs(z) < 1e-9, 1e-9, z)
    return np.stack([x / z - xx, y / z - yy], -1).astype(np.float32)


def residual_motion(fw, homographies) -> np.ndarray:
    """``(T-1,H,W)`` float32 magnitude of the flow minus each pair's homography flow
    (large where something moves independently of the camera)."""
    f, _ = _check_pair(fw)
    hs = np.asarray(homographies, dtype=np.float64)
    if hs.shape != (f.shape[0], 3, 3):
        raise LayercamError(f"expected homographies ({f.shape[0]},3,3), got {hs.shape}")
    h, w = f.shape[1:3]
    return np.stack(
        [np.linalg.norm(f[i] - _homography_flow(hs[i], h, w), axis=-1) for i in range(f.shape[0])]
    ).astype(np.float32).reshape(f.shape[:3])


# --------------------------------------------------------------------------------------------
# Optional: RAFT from a local weights file (never downloads)
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# Working resolution: flow of large frames is computed on smaller copies
# --------------------------------------------------------------------------------------------


                          # back scaled up: DIS's cost and memory grow with the pixels, its accuracy barely


                          # back scaled up: DIS's cost and memory grow with the pixels, its accuracy barely


