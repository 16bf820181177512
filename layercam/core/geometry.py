"""Frame geometry: homographies between frames, their chaining to a reference frame, and the
mappings from frames into an atlas.

Conventions, the one definition for the whole project: **pixel coordinates** ``(x, y)`` put the
centre of the pixel in column ``i``, row ``j`` at ``(i, j)``, as OpenCV, flow vectors and
``cv2.remap`` count them (:func:`pixel_grid`); a ``W x H`` frame covers ``[-0.5, W - 0.5] x [-0.5,
H - 0.5]`` (:func:`frame_corners`), and the same image at another size maps by
:func:`layercam.vision.scale.pixel_scaling`. **Normalised frame coordinates** are ``[-1, 1]`` over
the frame's edges (x along the width): ``x_n = (2 x + 1) / W - 1`` (:func:`normalised_frame_matrix`,
:func:`layercam.scene.coords.normalise_xy`, ``grid_sample(align_corners=False)``). Atlas
coordinates ``uv`` live in ``[-1, 1]^2``. Homographies are ``(3, 3)`` float64 arrays acting on
column vectors ``(x, y, 1)`` of pixel coordinates.

>>> import numpy as np
>>> shift = np.array([[1.0, 0, 2], [0, 1, 0], [0, 0, 1]])  # frame t -> t+1: 2 px to the right
>>> chain_homographies(np.stack([shift, shift]), ref=1)[:, 0, 2]  # each frame -> frame 1
array([ 2.,  0., -2.])
>>> max_corner_shift(chain_homographies(np.stack([shift, shift]), 1), 8, 8)
2.0
"""

from __future__ import annotations

import numpy as np

from layercam.core.errors import LayercamError


def pixel_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """``(xx, yy)``, each ``(h, w)`` float32: every pixel's coordinates (column, row), its centre in
    this module's convention."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return xx, yy


def warp(img, flow, border: str = "replicate") -> np.ndarray:
    """Backward warp: ``result(x) = img(x + flow(x))`` (bilinear, ``cv2.remap``).

    img: ``(H,W)`` or ``(H,W,C)`` (any C; float or uint8). flow: ``(H,W,2)``.
    border: "replicate" or "constant" (zeros outside). Returns img's dtype and shape.
    """
    import cv2

    im = np.asarray(img)
    fl = np.asarray(flow, dtype=np.float32)
    if im.ndim not in (2, 3) or fl.shape != im.shape[:2] + (2,):
        raise LayercamError(f"warp: img {im.shape} and flow {fl.shape} do not match")
    xx, yy = pixel_grid(*im.shape[:2])
    bmode = {"replicate": cv2.BORDER_REPLICATE, "constant": cv2.BORDER_CONSTANT}[border]
    src = im if im.dtype in (np.uint8, np.float32) else im.astype(np.float32)
    if src.ndim == 3 and src.shape[2] > 4:  # remap handles at most 4 channels
        out = np.stack(
            [cv2.remap(np.ascontiguousarray(src[..., c]), xx + fl[..., 0], yy + fl[..., 1],
                       cv2.INTER_LINEAR, borderMode=bmode) for c in range(src.shape[2])], -1)
    else:
        out = cv2.remap(np.ascontiguousarray(src), xx + fl[..., 0], yy + fl[..., 1],
                        cv2.INTER_LINEAR, borderMode=bmode)
        if src.ndim == 3 and out.ndim == 2:
            out = out[..., None]
    return out.astype(im.dtype, copy=False)


def middle_frame(n: int) -> int:
    """The middle of ``n`` frames (the later of the two middles for an even ``n``): the reference
    frame of the bootstrap's chained homographies, of the atlas export and of a fused stack.

    >>> middle_frame(4), middle_frame(5)
    (2, 2)
    """
    return int(n) // 2


def reference_index(ref, n: int) -> int:
    """The image a stack is fused into (``export.reference``) among ``n``: "middle" (the default,
    :func:`middle_frame`), "first", "last" or an index (negative counts from the end)."""
    from layercam.core.errors import LayercamError

    named = {"middle": middle_frame(n), "first": 0, "last": n - 1}
    if isinstance(ref, str) and ref.strip().lower() in named:
        return named[ref.strip().lower()]
    try:
        i = int(ref)
    except (TypeError, ValueError):
        raise LayercamError(f"reference must be middle, first, last or an image index, got {ref!r}") from None
    if not -n <= i < n:
        raise LayercamError(f"reference image {i} is out of range for {n} images")
    return i % n


def normalised_frame_matrix(h: int, w: int) -> np.ndarray:
    """Pixel coordinates -> normalised ``[-1, 1]`` coordinates (this module's conventions)."""
    return np.array([[2.0 / w, 0, 1.0 / w - 1], [0, 2.0 / h, 1.0 / h - 1], [0, 0, 1]], dtype=np.float64)


def chain_homographies(pair_h: np.ndarray, ref: int) -> np.ndarray:
    """Per-pair ``H_t: frame t -> frame t+1`` (pixels) -> ``M_t: frame t -> frame ref`` (pixels)."""
    n = len(pair_h) + 1
    m = [np.eye(3) for _ in range(n)]
    for t in range(ref - 1, -1, -1):
        m[t] = m[t + 1] @ pair_h[t]
    for t in range(ref + 1, n):
        m[t] = m[t - 1] @ np.linalg.inv(pair_h[t - 1])
    return np.stack([x / x[2, 2] for x in m])


def frame_corners(h: int, w: int) -> np.ndarray:
    """``(3, 4)``: the outer corners of an ``h x w`` frame in pixel coordinates, homogeneous columns."""
    return np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [-0.5, h - 0.5, 1],
                     [w - 0.5, h - 0.5, 1]], dtype=np.float64).T


def atlas_box(h: int, w: int) -> np.ndarray:
    """``(3, 4)``: the box the atlas framing measures a frame by, ``[0, W] x [0, H]`` in pixel
    coordinates: each pixel taken as the unit square from its coordinates, ``[x, x + 1]``, so the box
    is :func:`frame_corners` moved by half a pixel right and down. :func:`atlas_mappings` fits it into
    the atlas, :func:`max_corner_shift` measures corner motion on it, and the object mapping
    (:mod:`layercam.vision.segment.mapping`) takes a pixel's square's centre ``x + 0.5``. Framing the
    frame's true edges instead was measured worse on a real bracket (``docs/measurements.md``)."""
    return np.array([[0, 0, 1], [w, 0, 1], [0, h, 1], [w, h, 1]], dtype=np.float64).T


def atlas_mappings(h: int, w: int, pixel_maps: np.ndarray, margin: float = 0.9) -> np.ndarray:
    """Per-frame pixel maps into a reference view ``(T, 3, 3)`` -> ``(T, 3, 3)`` from normalised frame
    coordinates to atlas ``uv``, scaled isotropically so that every frame lands inside
    ``[-margin, margin]^2``."""
    corners = atlas_box(h, w)
    pts = []
    for m in pixel_maps:
        p = m @ corners
        pts.append((p[:2] / p[2:]).T)
    pts = np.concatenate(pts)
    lo, hi = pts.min(0), pts.max(0)
    return fit_into_atlas(pixel_maps, (lo + hi) / 2, (hi - lo).max() / 2, margin, h, w)


def fit_into_atlas(pixel_maps: np.ndarray, centre: np.ndarray, half: float, margin: float, h: int,
                   w: int) -> np.ndarray:
    """Pixel maps ``(T, 3, 3)`` -> normalised frame coordinates to atlas ``uv``, with the reference
    view's square of half-side ``half`` around ``centre`` (pixels) scaled to ``[-margin, margin]^2``."""
    s = margin / max(half, 1e-6)
    a = np.array([[s, 0, -s * centre[0]], [0, s, -s * centre[1]], [0, 0, 1]])
    n_inv = np.linalg.inv(normalised_frame_matrix(h, w))
    return np.stack([a @ m @ n_inv for m in pixel_maps]).astype(np.float32)


# A clip whose chained flow homographies move no frame corner by this much is registered by the
# identity: between frames of different focus or exposure such small homographies are mostly flow
# noise (up to 1 px on an aligned synthetic focus/exposure stack), and a wrong sub-pixel
# registration lets the scene store each frame apart instead of the blur generator explaining it.
STATIC_CORNER_PX = 1.5


def max_corner_shift(pixel_maps: np.ndarray, h: int, w: int) -> float:
    """Largest displacement (px) of a frame corner under the per-frame maps ``(T, 3, 3)``."""
    c = atlas_box(h, w)
    p = np.asarray(pixel_maps, dtype=np.float64) @ c  # (T, 3, 4)
    return float(np.abs(p[:, :2] / p[:, 2:] - c[:2]).max(initial=0.0))


def atlas_pixels(h0: np.ndarray, frame_hw: tuple[int, int]) -> float:
    """How many frame pixels span the atlas's ``[-1, 1]`` side, from the bootstrap mappings
    ``h0 (L, T, 3, 3)``: the largest over layers and frames of 2 / (uv step of one pixel)."""
    h, w = frame_hw
    h0 = np.asarray(h0, dtype=np.float64).reshape(-1, 3, 3)
    p0 = h0 @ np.array([0.0, 0.0, 1.0])
    px = h0 @ np.array([2.0 / w, 0.0, 1.0])
    py = h0 @ np.array([0.0, 2.0 / h, 1.0])
    uv0, uvx, uvy = (p[:, :2] / p[:, 2:] for p in (p0, px, py))
    step = np.minimum(np.linalg.norm(uvx - uv0, axis=1), np.linalg.norm(uvy - uv0, axis=1))
    return float(2.0 / max(step.min(), 1e-6))


def sampson_distance(f: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Sampson distance (px) of correspondences ``x1 -> x2`` ``(..., 2)`` to the epipolar geometry
    ``f`` ``(3, 3)``: the first-order distance of each pair to satisfying ``x2^T f x1 = 0``."""
    p1 = np.concatenate([x1, np.ones_like(x1[..., :1])], -1)
    p2 = np.concatenate([x2, np.ones_like(x2[..., :1])], -1)
    fx1, ftx2 = p1 @ f.T, p2 @ f
    num = (p2 * fx1).sum(-1) ** 2
    den = fx1[..., 0] ** 2 + fx1[..., 1] ** 2 + ftx2[..., 0] ** 2 + ftx2[..., 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-12))
