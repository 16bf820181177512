"""The ffmpeg binary every video goes through and what its log says: the input's header
(:func:`parse_header`), a frame rate read (:func:`ntsc`) and written (:func:`rate_text`) exactly,
the line that says why it failed (:func:`last_line`)."""

from __future__ import annotations

import re

__all__ = ["ffmpeg_exe", "last_line", "ntsc", "parse_header", "rate_text"]


def ffmpeg_exe() -> str:
    """The ffmpeg binary every video goes through: imageio-ffmpeg's (``IMAGEIO_FFMPEG_EXE`` names
    another)."""
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def ntsc(fps: float) -> float:
    """``fps`` as printed by ffmpeg (two decimals: 29.97) -> the NTSC rate it stands for
    (30000/1001) when it is one, else ``fps``."""
    n = round(fps * 1.001)
    if n >= 10 and abs(fps - n / 1.001) < 0.006 and abs(fps - round(fps)) > 0.006:
        return n * 1000 / 1001
    return fps


def rate_text(fps: float) -> str:
    """A frame rate as ffmpeg reads it exactly: ``"30000/1001"`` for NTSC rates, ``"25/2"``, ``"24"``."""
    from fractions import Fraction

    n = round(fps * 1.001)
    if abs(fps - n * 1000 / 1001) < 1e-9 * fps and abs(fps - round(fps)) > 1e-6:
        return f"{n * 1000}/1001"
    return str(Fraction(fps).limit_denominator(1001))


_STREAM = re.compile(r"Stream #0:\d+[^:]*: (Video|Audio): ([^\n]*)")
_TAGGED = ("bt709", "bt2020", "bt470bg", "smpte170m", "smpte240m", "smpte432", "smpte431", "bt470m",
           "film", "smpte428", "jedec-p22")


def parse_header(text: str) -> dict:
    """What ffmpeg's log says about its input file (the part before ``Output #0``): ``fps`` (the
    average rate, None when not said), ``tbr`` (the rate ffmpeg guesses, that a constant-rate
    decode uses), ``variable`` (the two differ by more than 0.1%), ``duration`` (seconds or None),
    ``video`` (its codec line), ``audio`` (the first audio stream's codec, or None) and
    ``primaries`` (the colour primaries the video is tagged with, or None)."""
    head = text.split("Output #0", 1)[0]
    out: dict = {"fps": None, "tbr": None, "variable": False, "duration": None, "video": None,
                 "audio": None, "primaries": None}
    m = re.search(r"Duration: (\d+):(\d+):(\d+(?:\.\d+)?)", head)
    if m:
        out["duration"] = int(m.group(1)) * 3600 + int(m.group(2)) * 60 + float(m.group(3))
    for kind, line in _STREAM.findall(head):
        if kind == "Audio" and out["audio"] is None:
            out["audio"] = line.split()[0].rstrip(",")
        elif kind == "Video" and out["video"] is None:
            out["video"] = line
            rates = {k: float(v) * (1000 if k_ else 1) for v, k_, k in re.findall(r"([\d.]+)(k?) (fps|tbr)\b", line)}
            out["fps"], out["tbr"] = rates.get("fps"), rates.get("tbr")
            if out["fps"] and out["tbr"]:
                out["variable"] = abs(out["fps"] - out["tbr"]) > 1e-3 * out["tbr"]
            colour = re.search(r", \w+\(([^)]*)\)", line)
            for tok in (colour.group(1).split(", ") if colour else []):
                parts = tok.split("/")
                name = parts[1] if len(parts) == 3 else parts[0]
                if name in _TAGGED:
                    out["primaries"] = name
    return out


def last_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1][:160] if lines else "no output from ffmpeg"
