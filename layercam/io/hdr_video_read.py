"""An HDR video :func:`layercam.io.hdr_video.write_hdr_video` wrote, read back (for checks and
figures): its light as the reference display shows it (:func:`read_hdr_video`), an SDR view of it
(:func:`sdr_view`) and what its header and first frame's side data say (:func:`probe_video`)."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np

from layercam.core import bt2100
from layercam.core.errors import LayercamError

__all__ = ["read_hdr_video", "probe_video", "sdr_view"]


def _decode(path: Path, pix_fmt: str, args: tuple[str, ...] = ()) -> tuple[bytes, str]:
    from layercam.io.ffmpeg import ffmpeg_exe

    res = subprocess.run([ffmpeg_exe(), "-nostdin", "-hide_banner", "-i", str(path), *args, "-map",
                          "0:v:0", "-f", "rawvideo", "-pix_fmt", pix_fmt, "-"],
                         stdin=subprocess.DEVNULL, capture_output=True)  # fmt: skip
    text = res.stderr.decode("utf-8", "replace")
    if res.returncode != 0:
        from layercam.io.ffmpeg import last_line

        raise LayercamError(f"cannot read video {path}: {last_line(text)}")
    return res.stdout, text


def read_hdr_video(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """Decode an HDR video written by :func:`layercam.io.hdr_video.write_hdr_video` (whole, for checks and figures) ->
    ``(light (T, H, W, 3) float32, info)``: BT.2020 linear light in cd/m2 as the reference display
    shows it (PQ: the EOTF; HLG: the inverse OETF and the 1000 cd/m2 display's OOTF). ``info``:
    :func:`probe_video`, and ``signal``: the non-linear R'G'B' ``(T, H, W, 3)``."""
    path = Path(path)
    info = probe_video(path)
    if info.get("transfer") not in ("smpte2084", "arib-std-b67"):
        raise LayercamError(f"{path} is not PQ or HLG (transfer {info.get('transfer')})")
    data, text = _decode(path, "yuv420p10le")
    w, h = info["width"], info["height"]
    n = len(data) // (w * h * 3)  # 2 bytes x 1.5 samples per pixel
    planes = np.frombuffer(data[: n * w * h * 3], "<u2").reshape(n, -1)
    y = planes[:, : w * h].reshape(n, h, w).astype(np.float64)
    uv = planes[:, w * h :].reshape(n, 2, h // 2, w // 2).astype(np.float64)
    up = np.repeat(uv, 2, axis=2)  # rows: each chroma row serves two
    full = np.empty((n, 2, h, w))
    full[..., 0::2] = up
    nxt = np.concatenate([up[..., 1:], up[..., -1:]], -1)
    full[..., 1::2] = 0.5 * (up + nxt)  # left-sited: the odd columns lie between two samples
    sig = bt2100.ycbcr_decode(np.stack([y, full[:, 0], full[:, 1]], -1))
    if info["transfer"] == "smpte2084":
        light = bt2100.pq_decode(sig)
    else:
        light = bt2100.hlg_ootf(bt2100.hlg_inverse_oetf(sig))
    info["signal"] = sig.astype(np.float32)
    return light.astype(np.float32), info


def sdr_view(light: np.ndarray, source_peak: float, white: float = bt2100.REFERENCE_WHITE) -> np.ndarray:
    """HDR display light ``(..., 3)`` (BT.2020, cd/m2) as an SDR screen shows it when the player tone
    maps it (as mpv / libplacebo do): diffuse white ``white`` becomes SDR's 100%, the light above it
    is rolled off by the BT.2390 EETF from ``source_peak`` (the file's MaxCLL) to ``white`` on each
    pixel's largest component, then BT.2020 -> BT.709 (clipped to its gamut) and the sRGB curve.
    Returns ``(..., 3)`` float32 in [0, 1]."""
    from layercam.core.colour import srgb_encode

    light = np.maximum(np.asarray(light, np.float64), 0.0)
    m = light.max(-1)
    ratio = np.where(m > 0, bt2100.eetf(m, max(source_peak, white), white) / np.maximum(m, 1e-30), 1.0)
    rgb = (light * ratio[..., None] / white) @ bt2100.primaries_matrix("bt2020", "bt709").T
    return srgb_encode(np.clip(rgb, 0.0, 1.0)).astype(np.float32)


_NUM = r"([\d.]+)"


def probe_video(path: str | os.PathLike) -> dict:
    """What ffprobe's ``-show_streams`` would say of a video's first video stream, from the bundled
    ffmpeg (which ships without ffprobe): its header (``ffmpeg -i``) and its first frame's side data
    (the ``showinfo`` filter). Keys: ``codec``, ``profile``, ``pix_fmt``, ``color_range``,
    ``color_space``, ``color_primaries``, ``transfer``, ``width``, ``height``, ``fps``, ``duration``,
    ``audio``; ``stream_side_data`` and ``frame_side_data`` (lines), ``mastering_display``
    (``{"r", "g", "b", "wp": (x, y), "min", "max"}`` from the stream, else the frame) and
    ``content_light`` (``{"max_cll", "max_fall"}``), None where absent."""
    from layercam.io.ffmpeg import parse_header

    path = Path(path)
    if not path.is_file():
        raise LayercamError(f"video not found: {path}")
    _, text = _decode(path, "gray", ("-frames:v", "1", "-vf", "showinfo"))  # the decoded first frame's side data
    head = text.split("Output #0", 1)[0]
    out = dict(parse_header(text))
    m = re.search(r"Stream #0:\d+[^:]*: Video: (\w+)(?: \(([^)]*)\))?[^,]*, (\w+)(?:\(([^)]*)\))?, (\d+)x(\d+)", head)
    if not m:
        raise LayercamError(f"{path} has no video stream")
    out.update(codec=m.group(1), profile=m.group(2), pix_fmt=m.group(3), width=int(m.group(5)), height=int(m.group(6)),
               color_range=None, color_space=None, color_primaries=None, transfer=None)  # fmt: skip
    for tok in (m.group(4) or "").split(", "):
        parts = tok.split("/")
        if tok in ("tv", "pc"):
            out["color_range"] = tok
        elif len(parts) == 3:
            out["color_space"], out["color_primaries"], out["transfer"] = parts
        elif tok and tok not in ("progressive",) and " " not in tok:
            out["color_space"] = out["color_primaries"] = out["transfer"] = tok
    block = re.search(r"Stream #0:\d+[^:]*: Video:.*?\n((?:\s{4,}.*\n)*)", head)
    stream_lines = [ln.strip() for ln in (block.group(1).splitlines() if block else [])]
    side = stream_lines[stream_lines.index("Side data:") + 1 :] if "Side data:" in stream_lines else []
    out["stream_side_data"] = [ln for ln in side
                               if ":" in ln
                               and not ln.startswith(("Metadata", "handler_name", "vendor_id",
                                                      "encoder"))]
    out["frame_side_data"] = re.findall(r"side data - ([^\n]*)", text)
    out["mastering_display"] = out["content_light"] = None
    for line in out["stream_side_data"] + out["frame_side_data"]:
        md = re.search(rf"r\({_NUM}[, ]\s*{_NUM}\) g\({_NUM}[, ]\s*{_NUM}\) b\({_NUM}[, "
                       rf"]\s*{_NUM}\) wp\({_NUM}[, ]\s*{_NUM}\) min_luminance={_NUM}, "
                       rf"max_luminance={_NUM}", line)
        if md and out["mastering_display"] is None:
            v = [float(x) for x in md.groups()]
            out["mastering_display"] = {"r": tuple(v[0:2]), "g": tuple(v[2:4]), "b": tuple(v[4:6]),
                                        "wp": tuple(v[6:8]), "min": v[8], "max": v[9]}
        cl = re.search(r"MaxCLL=(\d+), MaxFALL=(\d+)", line)
        if cl and out["content_light"] is None:
            out["content_light"] = {"max_cll": int(cl.group(1)), "max_fall": int(cl.group(2))}
    return out
