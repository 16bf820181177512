"""HDR video files people can watch: linear HDR frames -> HEVC Main 10 mp4 with BT.2020 primaries
and the PQ (HDR10, SMPTE ST 2084) or HLG (ARIB STD-B67) transfer, with mastering-display and
content-light-level metadata computed from the frames; and back (for checks and figures).

How the frames' relative radiance becomes light (:class:`HdrMapping`):

1. **Anchor**: the radiance ``white`` the caller names diffuse white (for a layercam run,
   :func:`layercam.scene.render.white_radiance`) becomes ``nits_white`` cd/m2 (BT.2408's HDR reference
   white, 203, unless told otherwise): one global scale, no curve. For HLG, white goes to the scene
   light that the BT.2100 reference display (1000 cd/m2, system gamma 1.2) shows at ``nits_white``
   (75% signal for 203).
2. **Colour**: the frames' primaries (BT.709 / sRGB for 8-bit input) -> BT.2020 by the 3x3 matrix
   in linear light (:func:`layercam.core.bt2100.primaries_matrix`).
3. **Highlights**: light above the display's peak (:data:`~layercam.core.bt2100.DISPLAY_PEAK`, 1000
   cd/m2; for HLG, scene light above 1) is rolled off by the BT.2390 EETF applied to each pixel's
   largest component, the pixel's RGB scaled by the same factor (hue kept); from the frames' own
   peak, so a clip within the peak is untouched.
4. **Signal**: PQ or HLG, Y'CbCr BT.2020 non-constant luminance, 10-bit narrow range, 4:2:0 with
   the chroma sited left (HEVC's default), piped to ffmpeg's libx265.

MaxCLL / MaxFALL (CTA-861.3: the brightest pixel's largest component, the brightest frame's mean of
it, in cd/m2 as the reference display shows the file) and the mastering display (the frames'
primaries, up to MaxCLL) are computed from the frames before they are encoded: the frames are read
three times (peak, light levels, encoding).
"""

from __future__ import annotations

import functools
import math
import os
import re
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from layercam.core import bt2100
from layercam.core.errors import LayercamError

__all__ = ["FORMATS", "TRANSFER", "HdrMapping", "missing_for_hdr", "write_hdr_video", "ANCHOR"]

FORMATS = ("pq", "hlg", "none")
TRANSFER = {"pq": "smpte2084", "hlg": "arib-std-b67"}
CRF = 10  # x265's quality: the codec's error within 2% of the light on most well-exposed pixels
          # (docs/measurements.md); 18 left 3%
PRESET = "fast"  # as medium's error and size, in three quarters of its time
MIN_SIDE = 16  # libx265 refuses smaller frames
NARROW = 64  # narrower frames are encoded padded to this width and cropped back (libx265 4.3's
             # 10-bit encoder crashes at widths 34..48)
ANCHOR = ("diffuse white = the radiance an SDR camera at the run's reference exposure (the median "
          "of its frames') records as signal 1.0: "
          "the learned camera's half signal at that exposure taken as sRGB's 0.5, i.e. 21.4% of "
          "white; it is shown at nits_white cd/m2 "
          "(BT.2408's HDR reference white, where SDR's 100% lands)")


@functools.lru_cache(maxsize=8)
def _ffmpeg_text(exe: str, *args: str) -> str:
    try:
        res = subprocess.run([exe, "-hide_banner", *args], stdin=subprocess.DEVNULL,
                             capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return ""
    return res.stdout + res.stderr


def missing_for_hdr(exe: str | None = None) -> str | None:
    """What the ffmpeg ``exe`` (default: :func:`layercam.io.ffmpeg.ffmpeg_exe`) lacks to write HDR
    video: None, or a phrase naming it ("libx265 encoder")."""
    from layercam.io.ffmpeg import ffmpeg_exe

    exe = exe or ffmpeg_exe()
    if not re.search(r"^\s*V\S*\s+libx265\s", _ffmpeg_text(exe, "-encoders"), re.M):
        return "libx265 encoder"
    return None


def _side_data_options(exe: str) -> bool:
    """Whether ``exe`` takes ``-mastering_display`` / ``-content_light`` on an input (ffmpeg 8 and
    later): then the mp4 also holds the metadata as boxes (mdcv, clli), not only as SEI in the HEVC
    stream."""
    return "-mastering_display" in _ffmpeg_text(exe, "-h", "long")


@dataclass
class HdrMapping:
    """Linear HDR frames ``(H, W, 3)`` (radiance, in ``primaries``) -> the light and signal of an
    HDR video (the module's docstring). ``scale``: light per unit of radiance, in cd/m2 for PQ
    and in 1000 x scene light for HLG (so that both roll off towards 1000); ``source_peak``: the
    frames' brightest light in those units (:meth:`peak_of`), where the roll-off starts from."""

    fmt: str
    scale: float
    primaries: str = "bt709"
    source_peak: float = 0.0
    peak: float = bt2100.DISPLAY_PEAK

    @classmethod
    def anchored(cls, fmt: str, white: float, nits_white: float = bt2100.REFERENCE_WHITE,
                 primaries: str = "bt709") -> "HdrMapping":
        """The mapping that shows radiance ``white`` (diffuse white) at ``nits_white`` cd/m2."""
        if fmt not in TRANSFER:
            raise LayercamError(f"HDR format must be one of {', '.join(TRANSFER)}, got {fmt!r}")
        if not (math.isfinite(white) and white > 0):
            raise LayercamError(f"diffuse white must be a positive radiance, got {white}")
        if not (math.isfinite(nits_white) and 0 < nits_white <= bt2100.DISPLAY_PEAK):
            raise LayercamError(f"nits_white must be in (0, {bt2100.DISPLAY_PEAK:g}] cd/m2, got {nits_white}")
        target = nits_white if fmt == "pq" else bt2100.DISPLAY_PEAK * (nits_white
            / bt2100.DISPLAY_PEAK) ** (1 / bt2100.hlg_gamma())
        return cls(fmt, target / white, primaries)

    @functools.cached_property
    def matrix(self) -> np.ndarray:
        return bt2100.primaries_matrix(self.primaries, "bt2020").astype(np.float32)

    def light(self, img: np.ndarray) -> np.ndarray:
        """Radiance ``(H, W, 3)`` -> BT.2020 linear light in the units of ``scale``, before the roll-off."""
        img = np.asarray(img, np.float32)
        return np.maximum(img @ (self.matrix.T * np.float32(self.scale)), 0.0)

    def peak_of(self, img: np.ndarray) -> float:
        return float(self.light(img).max(initial=0.0))

    def _rolled(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`light` before the roll-off, its largest component and the roll-off's factor (1
        below the knee; the EETF is evaluated only above it)."""
        lin = self.light(img)
        m = lin.max(-1)
        ratio = np.ones_like(m)
        above = m > bt2100.eetf_knee(self.source_peak, self.peak)
        if above.any():
            ratio[above] = bt2100.eetf(m[above], self.source_peak, self.peak) / m[above]
        return lin, m, ratio

    def rolled(self, img: np.ndarray) -> np.ndarray:
        """:meth:`light` with the BT.2390 roll-off on each pixel's largest component (ratios kept)."""
        lin, _, ratio = self._rolled(img)
        return lin * ratio[..., None]

    def display(self, img: np.ndarray) -> np.ndarray:
        """The light in cd/m2 (BT.2020 RGB) that the reference display shows for ``img``."""
        r = self.rolled(img)
        return r if self.fmt == "pq" else bt2100.hlg_ootf(r / bt2100.DISPLAY_PEAK).astype(np.float32)

    def display_max(self, img: np.ndarray) -> np.ndarray:
        """``display(img).max(-1)`` ``(H, W)``, without the whole display image (CTA-861.3's light level)."""
        lin, m, ratio = self._rolled(img)
        if self.fmt == "pq":
            return m * ratio
        ys = (lin @ np.asarray(bt2100.LUMA_2020, np.float32)) * ratio / bt2100.DISPLAY_PEAK
        return (bt2100.DISPLAY_PEAK * np.power(np.maximum(ys, 1e-12), bt2100.hlg_gamma() - 1) * m
                * ratio / bt2100.DISPLAY_PEAK).astype(np.float32)

    def signal(self, img: np.ndarray) -> np.ndarray:
        """Non-linear R'G'B' in [0, 1] ``(H, W, 3)`` float32."""
        r = self.rolled(img)
        return bt2100.pq_encode(r) if self.fmt == "pq" else bt2100.hlg_oetf(r / np.float32(bt2100.DISPLAY_PEAK))


def _yuv420(rgb_signal: np.ndarray) -> bytes:
    """R'G'B' ``(H, W, 3)`` (even H, W) -> planar yuv420p10le bytes: chroma averaged over each two
    rows and filtered [1, 2, 1] / 4 across columns at the even ones (left-sited, HEVC's default)."""
    c = bt2100.ycbcr_encode(rgb_signal, rounded=False)
    y = np.clip(np.round(c[..., 0]), 0, 1023).astype("<u2")
    ch = 0.5 * (c[0::2, :, 1:] + c[1::2, :, 1:])  # (H/2, W, 2)
    left = np.concatenate([ch[:, :1], ch[:, :-1]], 1)
    right = np.concatenate([ch[:, 1:], ch[:, -1:]], 1)
    ch = (0.25 * left + 0.5 * ch + 0.25 * right)[:, 0::2]
    uv = np.clip(np.round(ch), 0, 1023).astype("<u2")
    return y.tobytes() + np.ascontiguousarray(uv[..., 0]).tobytes() + np.ascontiguousarray(uv[..., 1]).tobytes()


def _even(img: np.ndarray, pad: int = 0) -> np.ndarray:
    """``img`` padded (repeating its last row / column) to an even size, and ``pad`` columns wider."""
    h, w = img.shape[:2]
    return np.pad(img, ((0, h % 2), (0, w % 2 + pad), (0, 0)), mode="edge") if h % 2 or w % 2 or pad else img


def _master_display(primaries: str, hi: float) -> str:
    """x265 / ffmpeg's mastering display: G, B, R and the white point in 0.00002 units, the
    luminance range in 0.0001 cd/m2: from 0.0001 (the frames' black is the display's; the
    smallest value the metadata holds) to ``hi`` (held within HEVC's 5..10000 cd/m2)."""
    (r, g, b), w = bt2100.PRIMARIES[primaries], bt2100.D65

    def xy(p):
        return f"({round(p[0] / 0.00002)},{round(p[1] / 0.00002)})"

    return f"G{xy(g)}B{xy(b)}R{xy(r)}WP{xy(w)}L({round(min(max(hi, 5.0), bt2100.PQ_PEAK) * 10000)},1)"


def write_hdr_video(path: str | os.PathLike, frames: Callable[[], Iterable[np.ndarray]], fps: float,
                    fmt: str, white: float,
                    nits_white: float = bt2100.REFERENCE_WHITE, primaries: str = "bt709", audio: dict | None = None,
                    crf: int = CRF, progress: bool = False) -> dict:
    """Write ``path`` (an mp4, atomically): the linear HDR frames that each call of ``frames()``
    yields (``(H, W, 3)`` float radiance in ``primaries``, all of one size; called three times) as
    an HEVC Main 10 video in ``fmt`` ("pq" or "hlg") at ``fps``, radiance ``white`` shown at
    ``nits_white`` cd/m2 (:class:`HdrMapping`), with ``audio`` carried over
    (:func:`layercam.io.video.mux_audio`). Returns what it wrote (the report's ``hdr_video``).
    Raises ``LayercamError`` (one line) when ffmpeg lacks libx265 or fails."""
    from layercam.io.atomic import ensure_writable_dir, temp_name
    from layercam.io.ffmpeg import ffmpeg_exe, last_line, rate_text
    from layercam.io.video import finish_with_audio, mp4_complete
    from layercam.core.progress import bar

    t0 = time.perf_counter()
    exe = ffmpeg_exe()
    missing = missing_for_hdr(exe)
    if missing:
        raise LayercamError(f"cannot write an HDR video: ffmpeg ({exe}) has no {missing}")
    path = Path(path)
    mp = HdrMapping.anchored(fmt, white, nits_white, primaries)
    n, size = 0, None
    for img in frames():  # pass 1: the frames' peak, where the roll-off starts from
        if not np.isfinite(img).all():
            raise LayercamError(f"frame {n} of the HDR video is not finite; not writing {path.name}")
        mp.source_peak = max(mp.source_peak, mp.peak_of(img))
        size = size or img.shape[:2]
        if img.shape[:2] != size:
            raise LayercamError(f"HDR video frames must all be {size[1]}x{size[0]}, got {img.shape[1]}x{img.shape[0]}")
        n += 1
    if n == 0:
        raise LayercamError(f"no frames for {path.name}")
    if min(size) < MIN_SIDE:
        raise LayercamError(f"cannot write {path.name}: libx265 encodes frames of at least "
                            f"{MIN_SIDE} px a side, these are {size[1]}x{size[0]}")
    cll, fall = 0.0, 0.0
    for img in frames():  # pass 2: the light levels of what the reference display shows
        m = mp.display_max(img)
        cll, fall = max(cll, float(m.max())), max(fall, float(m.mean(dtype=np.float64)))
    max_cll, max_fall = max(1, math.ceil(cll)), max(1, math.ceil(fall))
    master = _master_display(primaries, max_cll)
    trc = TRANSFER[fmt]

    ensure_writable_dir(path.parent)
    h, w = size[0] + size[0] % 2, size[1] + size[1] % 2
    pad = max(0, NARROW - w)  # encoded wider, cropped back by the stream's conformance window
    side = _side_data_options(exe)
    params = [f"log-level=error", "colorprim=bt2020", f"transfer={trc}", "colormatrix=bt2020nc",
              "range=limited", "chromaloc=0",
              f"master-display={master}", f"max-cll={max_cll},{max_fall}", "hdr10=1"]
    colour = ["-color_primaries", "bt2020", "-color_trc", trc, "-colorspace", "bt2020nc", "-color_range", "tv"]
    cmd = [exe, "-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt",
           "yuv420p10le", "-s", f"{w + pad}x{h}", "-framerate", rate_text(fps),
           *(["-mastering_display", master, "-content_light", f"{max_cll},{max_fall}"] if side
             else []), *colour, "-i", "-",
           "-c:v", "libx265", "-preset", PRESET, "-crf", str(crf), "-profile:v", "main10",
           "-pix_fmt", "yuv420p10le", "-x265-params", ":".join(params),
           *colour, "-chroma_sample_location", "left", *(["-bsf:v", f"hevc_metadata=crop_right={pad}"] if pad else []),
           "-tag:v", "hvc1", "-movflags", "+faststart"]  # fmt: skip
    tmp = temp_name(path)
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen([*cmd, str(tmp)], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log)
        try:
            try:
                for img in bar(frames(), total=n, desc=f"{path.name} ({fmt})", unit="frame",
                               enabled=progress):  # pass 3: encode
                    proc.stdin.write(_yuv420(mp.signal(_even(np.asarray(img, np.float32), pad))))
                proc.stdin.close()
            except (BrokenPipeError, OSError):
                pass  # ffmpeg stopped: its log says why
            rc = proc.wait()
        except BaseException:
            proc.kill()
            proc.wait()
            tmp.unlink(missing_ok=True)
            raise
        log.seek(0)
        text = log.read().decode("utf-8", "replace")
    if rc != 0 or not tmp.is_file() or not mp4_complete(tmp):
        tmp.unlink(missing_ok=True)
        full = " (is the disk full?)" if "No space left" in text or rc == 0 else ""
        raise LayercamError(f"cannot write {path}{full}: ffmpeg failed ({last_line(text)})")

    sound = finish_with_audio(tmp, path, audio)
    return {"file": path.name, "format": fmt, "transfer": trc,
            "codec": "hevc main10 yuv420p10le bt2020nc", "frames": n, "fps": rate_text(fps),
            "nits_white": nits_white, "white_radiance": white, "scale": float(mp.scale), "primaries_in": primaries,
            "source_peak": round(mp.source_peak, 2), "display_peak": mp.peak,
            "rolled_off": bool(mp.source_peak > mp.peak),
            "max_cll": max_cll, "max_fall": max_fall, "master_display": master,
            "metadata": "mp4 boxes and SEI" if side else "SEI",
            "audio": sound, "seconds": round(time.perf_counter() - t0, 2)}  # fmt: skip
