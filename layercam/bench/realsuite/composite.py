"""Alternating-exposure clips with ground truth, rendered from real material.

The background is a real radiance map (``bracket_taipei``'s 10 shots merged with their times), the
foreground a real non-rigid subject cut out of a DAVIS clip with its ground-truth masks (the person
of ``layers_davis_parkour`` by default). A camera pans over the background (a window moving from its
left edge to its right edge over the clip, rising by a tenth of the room it has; held at its middle
with ``still``) while the subject moves as it did in its own clip. The composite is formed in linear
radiance (the ground truth per frame), then exposed with times alternating by ``ev_step`` (frame 0
the short one), given shot and
read noise, clipped at full well, put through a camera curve that is none of ``layercam.synth``'s
(:func:`filmic`: Hable's filmic toe and shoulder, then gamma 1/2.2, with a different shoulder
per channel) and quantised to 8 bits.

:func:`compose` is pure (arrays in, arrays out; seeded); :func:`load_background` and
:func:`load_foreground` read the shared captures.

Camera shake over a real still (:class:`ShakeSpec`, :func:`shake_still`): a sharp frame of real
footage, linearised, shaken along known hand-held paths and blurred in linear light; the sharp frames
(each at its path's mid point) are the truth. It isolates what deblurring a hand-held clip needs when
nothing in it moves on its own.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError

__all__ = ["CompositeSpec", "filmic", "compose", "expose", "load_background", "load_foreground",
           "ShakeSpec", "shake_still", "load_still"]

# Hable's filmic curve constants (shoulder, linear, toe strengths and angles)
_A, _B, _C, _D, _E, _F = 0.15, 0.50, 0.10, 0.20, 0.02, 0.30
FILMIC_WHITE = (4.6, 5.0, 5.6)  # per channel R, G, B: how far into the shoulder full well reaches


@dataclass(frozen=True)
class CompositeSpec:
    """What a composite clip is made of. ``size`` is (H, W); the noise is in units of full well
    (``shot``: variance per unit of signal, i.e. 1 / full-well electrons; ``read``: std).
    ``bg_level`` and ``fg_level``: the background's and the subject's median luminance, as a
    fraction of the long exposure's full well (they set the exposure and the subject's radiance)."""

    frames: int = 24
    size: tuple[int, int] = (256, 384)
    ev_step: float = 2.0
    seed: int = 0
    shot: float = 1.0 / 4000.0
    read: float = 0.001
    bg_level: float = 0.2
    fg_level: float = 0.3
    fg_clip: str = "layers_davis_parkour"
    still: bool = False  # the camera held at the middle of the pan: the export merges neighbours (a static camera)

    def key(self) -> dict:
        return asdict(self)


def _hable(x: np.ndarray) -> np.ndarray:
    return (x * (_A * x + _C * _B) + _D * _E) / (x * (_A * x + _B) + _D * _F) - _E / _F


def filmic(x: np.ndarray, white=FILMIC_WHITE) -> np.ndarray:
    """Camera curve: sensor value ``x`` in [0, 1] (1 = full well) -> encoded value in [0, 1].
    ``(..., 3)`` -> ``(..., 3)``; channel c is ``(H(w_c x) / H(w_c)) ** (1/2.2)`` with Hable's
    filmic ``H``; monotone, 0 -> 0 and 1 -> 1."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    w = np.asarray(white, np.float64)
    return (_hable(x * w) / _hable(w)) ** (1.0 / 2.2)


def exposure_times(spec: CompositeSpec, hdr: np.ndarray) -> np.ndarray:
    """``(T,)`` exposure times alternating short, long, ...; the long one puts the median luminance
    of ``hdr`` (the background) at ``bg_level`` of full well."""
    t_long = spec.bg_level / max(float(np.median(hdr.mean(axis=-1))), 1e-12)
    t_short = t_long / 2.0 ** spec.ev_step
    return np.where(np.arange(spec.frames) % 2 == 0, t_short, t_long)


def expose(hdr: np.ndarray, times: np.ndarray, rng: np.random.Generator | None, spec: CompositeSpec) -> np.ndarray:
    """Frames a camera records of radiance ``hdr`` ``(T,H,W,3)`` at ``times`` ``(T,)``: sensor
    value ``hdr * t`` plus shot and read noise (none when ``rng`` is None), clipped at full well,
    through :func:`filmic`, quantised to 8 bits. Returns ``(T,H,W,3)`` uint8."""
    x = hdr.astype(np.float64) * np.asarray(times, np.float64)[:, None, None, None]
    if rng is not None:
        sd = np.sqrt(spec.shot * np.clip(x, 0.0, None) + spec.read**2)
        x = x + rng.standard_normal(x.shape) * sd
    return np.round(filmic(x) * 255.0).astype(np.uint8)


def _window(bg: np.ndarray, t: int, spec: CompositeSpec) -> np.ndarray:
    """The camera's view of the background at frame ``t``: the background scaled so that its height
    is 1.25 frame heights, a frame-sized window moving linearly from the left edge to the right
    edge and up by a tenth of its vertical room (held at its middle frame's place with ``spec.still``);
    bilinear on linear radiance. ``(H, W, 3)``."""
    import cv2

    h, w = spec.size
    s = 1.25 * h / bg.shape[0]
    if bg.shape[1] * s < w * 1.1:
        s = 1.1 * w / bg.shape[1]
    room_x, room_y = bg.shape[1] * s - w, bg.shape[0] * s - h
    f = ((spec.frames - 1) // 2 if spec.still else t) / max(spec.frames - 1, 1)
    x0, y0 = f * room_x, room_y * (1.0 - 0.1 * f)
    m = np.array([[s, 0.0, -x0], [0.0, s, -y0]], np.float64)
    return cv2.warpAffine(bg, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def _place(img: np.ndarray, spec: CompositeSpec) -> np.ndarray:
    """A foreground frame (its own clip's size) scaled to the frame height and centred."""
    import cv2

    h, w = spec.size
    s = h / img.shape[0]
    m = np.array([[s, 0.0, (w - img.shape[1] * s) / 2.0], [0.0, s, 0.0]], np.float64)
    return cv2.warpAffine(img, m, (w, h), flags=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def compose(background: np.ndarray, fg_rgb: np.ndarray, fg_alpha: np.ndarray, spec: CompositeSpec) -> dict:
    """Render a composite clip.

    background: ``(Hb,Wb,3)`` linear radiance (any scale); fg_rgb: ``(T,Hf,Wf,3)`` the subject's
    frames, display-referred sRGB in [0,1]; fg_alpha: ``(T,Hf,Wf)`` its mask in [0,1] (T >= frames).
    Returns ``{"frames": (T,H,W,3) uint8, "hdr": (T,H,W,3) float32 linear ground truth,
    "alpha": (T,H,W) float32 subject coverage, "times": (T,) exposure times}``.
    """
    n = spec.frames
    if fg_rgb.shape[0] < n or fg_alpha.shape[0] < n:
        raise LayercamError(f"the foreground has {fg_rgb.shape[0]} frames, the composite needs {n}")
    if background.ndim != 3 or background.shape[2] != 3 or not np.all(np.isfinite(background)) or background.max() <= 0:
        raise LayercamError("the background must be a finite, positive (H, W, 3) radiance map")
    bg = np.stack([_window(background.astype(np.float32), t, spec) for t in range(n)])
    fg_lin = np.where(fg_rgb <= 0.04045, fg_rgb / 12.92,
                      ((np.clip(fg_rgb, 0, 1) + 0.055) / 1.055) ** 2.4).astype(np.float32)
    fg = np.stack([_place(fg_lin[t], spec) for t in range(n)])
    alpha = np.clip(np.stack([_place(fg_alpha[t].astype(np.float32), spec) for t in range(n)]), 0.0, 1.0)
    if not (alpha > 0.5).any():
        raise LayercamError("the foreground's masks are empty at this size")
    # levels: the background's and the subject's median luminance at bg_level and fg_level of the
    # long exposure's full well
    times = exposure_times(spec, bg)
    fg_lum = fg.mean(axis=-1)[alpha > 0.5]
    k = spec.fg_level / times.max() / max(float(np.median(fg_lum)), 1e-6)
    hdr = alpha[..., None] * fg * k + (1.0 - alpha[..., None]) * bg
    frames = expose(hdr, times, np.random.default_rng(spec.seed), spec)
    return {"frames": frames, "hdr": hdr.astype(np.float32), "alpha": alpha.astype(np.float32), "times": times}


# -- camera shake over a real still ------------------------------------------------------------
@dataclass(frozen=True)
class ShakeSpec:
    """A real still frame shaken by a hand-held camera: ``frames`` of ``size`` (H, W), each the mean
    in linear light of sub-frames along a smooth random path whose extent runs from 0.2 px to
    ``max_blur_px`` over the clip (shuffled), around a slow pan; sRGB, noise of sd ``noise``, 8 bits
    (:func:`layercam.synth.shake_blur` with the still as its canvas). The still is ``source``'s
    sharp frame ``still`` at ``scale``."""

    frames: int = 12
    size: tuple[int, int] = (256, 448)
    max_blur_px: float = 8.0
    noise: float = 0.005
    seed: int = 0
    source: str = "deblur_gopro0477_dev"
    still: int = 6
    scale: float = 0.5

    def key(self) -> dict:
        return asdict(self)


def load_still(data: Path, spec: ShakeSpec) -> np.ndarray:
    """``source/sharp``'s frame ``still`` at ``scale``, in linear light ``(H, W, 3)`` float32."""
    from layercam.io import load_clip

    folder = Path(data) / spec.source / "sharp"
    names = sorted(p for p in folder.iterdir()
                   if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".tif",
                                           ".tiff")) if folder.is_dir() else []
    if len(names) <= spec.still:
        raise LayercamError(f"{folder} has {len(names)} frames, frame {spec.still} needed")
    img = load_clip([names[spec.still]], resize=f"{spec.scale:g}").frames[0]
    return np.where(img <= 0.04045, img / 12.92, ((img + 0.055) / 1.055) ** 2.4).astype(np.float32)


def shake_still(still: np.ndarray, spec: ShakeSpec) -> dict:
    """Shake ``still`` (linear ``(Hs, Ws, 3)``, larger than ``spec.size`` by the path) as ``spec``
    says. Returns ``{"frames": (T,H,W,3) uint8, "sharp": (T,H,W,3) float32 sRGB in [0, 1] (each frame
    at its path's mid point, noise-free), "blur_length": (T,) px}``."""
    from layercam.synth import shake_blur

    sc = shake_blur(frames=spec.frames, size=spec.size, max_blur_px=spec.max_blur_px,
                    noise=spec.noise, seed=spec.seed, canvas=still)
    frames = np.round(np.asarray(sc.clip.frames, np.float64) * 255.0).astype(np.uint8)
    return {"frames": frames, "sharp": np.asarray(sc.sharp_ldr, np.float32),
            "blur_length": np.asarray(sc.meta["blur_length"], np.float32)}


# -- the real material --------------------------------------------------------------------------
def load_background(data: Path) -> np.ndarray:
    """``bracket_taipei``'s 10 shots merged with their listed times (OpenCV Robertson:
    :func:`layercam.bench.realsuite.classical.robertson_reference`). ``(510, 768, 3)`` float32."""
    from layercam.io import load_clip
    from layercam.bench.realsuite.classical import robertson_reference

    folder = Path(data) / "bracket_taipei"
    times = read_image_list(folder / "image_list.txt")
    names = sorted(times)
    clip = load_clip([folder / n for n in names])
    return robertson_reference(clip.frames, np.array([times[n] for n in names]))


def read_image_list(path: Path) -> dict[str, float]:
    """``bracket_taipei/image_list.txt``: ``name time 1/time`` lines -> ``{name: seconds}``."""
    out = {}
    for line in Path(path).read_text().splitlines():
        tok = line.split("#", 1)[0].split()
        if len(tok) >= 2:
            out[tok[0]] = float(tok[1])
    if not out:
        raise LayercamError(f"no exposure times in {path}")
    return out


def load_foreground(data: Path, clip: str, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The first ``frames`` frames of a DAVIS clip and its ground-truth masks:
    ``(T,480,854,3)`` sRGB in [0,1] and ``(T,480,854)`` float in {0, 1}."""
    from layercam.io import read_image

    folder = Path(data) / clip
    imgs = sorted((folder / "frames").glob("*.jpg"))[:frames]
    masks = sorted((folder / "masks_gt").glob("*.png"))[:frames]
    if len(imgs) < frames or len(masks) < frames:
        raise LayercamError(f"{folder} has {len(imgs)} frames and {len(masks)} masks, {frames} needed")
    rgb = np.stack([read_image(p) for p in imgs])
    alpha = np.stack([(read_image(p).max(axis=-1) > 0.5).astype(np.float32) for p in masks])
    return rgb, alpha
