"""The camera's response measured from the clip's own matches (Debevec & Malik 1997), before training.

Two neighbouring frames of different exposure that the flow matches see the same irradiance ``E``
at matched pixels ``a`` (frame ``t``) and ``b`` (frame ``t + 1``): with ``g`` the log2 inverse of the
response, ``g(b) - g(a) = log2 dt_{t+1} - log2 dt_t``. :func:`fit_response` solves these equations for
``g`` on every code (least squares, the hat weights and the second-difference smoothness of Debevec
and Malik) with ``g(WHITE_POINT) = 0`` (the paper's ``T(0) = 0.5``); the tone mapper then starts from
that curve (:func:`layercam.camera.tone.fit_init_curve`) instead of a sigmoid, and the atlases from its
inverse (:func:`layercam.camera.tone.initial_log2`). Training still learns the curve (paper Sec. 3.3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KNOTS = 256  # g on every 8-bit code (16-bit input: interpolated between them)
SMOOTH = 1.0  # Debevec-Malik's lambda, relative to the matches per code: bridges codes no match holds and
              # bends the curve less where few do; more would straighten a real camera's knee
MATCHES = 2**18  # matched pixels drawn in all, shared by the pairs of frames whose exposures differ: some
                 # hundred per code, whatever the clip's length (memory: about 30 MB a channel to solve)


@dataclass(frozen=True)
class Response:
    """``g (3, K)``: log2 exposure (irradiance x time; 0 at the white point) of each code ``codes (K,)``
    per channel, increasing; codes no match held are bridged by the smoothness."""

    codes: np.ndarray
    g: np.ndarray

    def logits(self, z: np.ndarray) -> np.ndarray:
        """The response's logit at log2 exposures ``z (N, 3)`` -> ``(N, 3)``: interpolated between
        the codes inside ``(0, 1)``, continued straight (in logit) past the end codes."""
        c = self.codes[1:-1]
        lg = np.log(c / (1 - c))
        out = np.empty_like(z, dtype=np.float64)
        for k in range(3):
            g = self.g[k, 1:-1]
            y = np.interp(z[:, k], g, lg)
            s0 = (lg[4] - lg[0]) / max(g[4] - g[0], 1e-6)
            s1 = (lg[-1] - lg[-5]) / max(g[-1] - g[-5], 1e-6)
            y = np.where(z[:, k] < g[0], lg[0] + s0 * (z[:, k] - g[0]), y)
            out[:, k] = np.where(z[:, k] > g[-1], lg[-1] + s1 * (z[:, k] - g[-1]), y)
        return out

    def inverse(self, c: np.ndarray) -> np.ndarray:
        """log2 exposure of grey codes ``c`` (any shape) through the channels' mean ``g``."""
        return np.interp(c, self.codes, self.g.mean(0))


def matched_codes(frames, log2_dt: np.ndarray, flow, total: int = MATCHES, seed: int = 0):
    """Codes of the pixels the flow matches between neighbours whose exposures differ: ``a``, ``b``
    ``(N, 3)`` in ``[0, 1]`` (frame ``t``, frame ``t + 1``) and ``dz (N,)`` their log2 exposure step.
    ``flow``: the flow stage's arrays (``fw``, ``fw_ok``, ``vis`` on its working grid): only pixels whose
    flow is consistent and that both frames see well (not clipped, above the floor, textured), where
    a match is to be trusted. None when no pair differs or none matches."""
    rng = np.random.default_rng(seed)
    dt = np.asarray(log2_dt, dtype=np.float64)
    pairs = [t for t in range(len(dt) - 1) if abs(dt[t + 1] - dt[t]) >= 1e-3]
    per_pair = max(1, total // max(len(pairs), 1))
    a, b, dz = [], [], []
    for t in pairs:
        ok = np.asarray(flow.fw_ok[t]) & np.asarray(flow.vis[t])  # consistent, and seen well by both (the homographies' pixels)
        h, w = ok.shape
        ys, xs = np.nonzero(ok)
        if len(ys) == 0:
            continue
        pick = rng.choice(len(ys), min(per_pair, len(ys)), replace=False)
        ys, xs = ys[pick], xs[pick]
        fw = np.asarray(flow.fw[t], dtype=np.float32)[ys, xs]
        f0, f1 = frames[t], frames[t + 1]
        H, W = f0.shape[:2]
        sy, sx = H / h, W / w
        y0 = np.minimum((ys * sy + rng.random(len(ys)) * sy).astype(int), H - 1)  # a frame pixel inside the grid cell
        x0 = np.minimum((xs * sx + rng.random(len(xs)) * sx).astype(int), W - 1)
        x1, y1 = x0 + fw[:, 0] * sx, y0 + fw[:, 1] * sy
        inside = (x1 >= 0) & (x1 <= W - 1) & (y1 >= 0) & (y1 <= H - 1)
        a.append(f0[y0[inside], x0[inside]])
        b.append(_bilinear(f1, x1[inside], y1[inside]))
        dz.append(np.full(int(inside.sum()), dt[t + 1] - dt[t]))
    if not a:
        return None
    return np.concatenate(a), np.concatenate(b), np.concatenate(dz)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    x0 = np.clip(np.floor(x).astype(int), 0, img.shape[1] - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, img.shape[0] - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx
    bot = img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bot * fy


def fit_response(a: np.ndarray, b: np.ndarray, dz: np.ndarray, white: float = 0.5) -> Response | None:
    """Debevec-Malik's least squares for ``g`` per channel from matched codes ``a``, ``b`` ``(N, 3)``
    and their steps ``dz (N,)``: ``w (g(b) - g(a) - dz) = 0`` with the hat weight ``w`` (codes near 0
    or 1 say little), ``SMOOTH`` on ``g''``, ``g(white) = 0``. None when a channel has no usable match."""
    from scipy import sparse
    from scipy.sparse.linalg import spsolve

    K = KNOTS
    codes = np.linspace(0.0, 1.0, K)
    out = []
    for k in range(3):
        ak, bk = a[:, k].astype(np.float64), b[:, k].astype(np.float64)
        wt = np.minimum(np.minimum(ak, 1 - ak), np.minimum(bk, 1 - bk))
        keep = wt > 1.0 / (K - 1)  # neither code at its end (clipped or black)
        n = int(keep.sum())
        if n < K:
            return None
        ak, bk, wt, d = ak[keep], bk[keep], wt[keep], dz[keep]
        rows = np.arange(n)
        ia, fa = _knot(ak, K)
        ib, fb = _knot(bk, K)
        data = np.concatenate([wt * (1 - fb), wt * fb, -wt * (1 - fa), -wt * fa])
        cols = np.concatenate([ib, ib + 1, ia, ia + 1])
        A = sparse.csr_matrix((data, (np.tile(rows, 4), cols)), shape=(n, K))
        smooth = SMOOTH * np.sqrt(n / K)
        D = sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(K - 2, K)) * smooth
        iw, fw = _knot(np.array([white]), K)
        gauge = sparse.csr_matrix(([(1 - fw[0]) * np.sqrt(n), fw[0] * np.sqrt(n)], ([0, 0], [iw[0], iw[0] + 1])), shape=(1, K))
        M = sparse.vstack([A, D, gauge]).tocsr()
        rhs = np.concatenate([wt * d, np.zeros(K - 2), [0.0]])
        g = spsolve((M.T @ M).tocsc(), M.T @ rhs)
        g = np.maximum.accumulate(g + np.arange(K) * 1e-6)  # increasing: the inverse is a function
        out.append(g - np.interp(white, codes, g))
    return Response(codes, np.stack(out))


def _knot(c: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray]:
    p = np.clip(c, 0.0, 1.0) * (K - 1)
    i = np.clip(np.floor(p).astype(int), 0, K - 2)
    return i, p - i
