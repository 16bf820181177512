"""Exposure times read from text: one time (``0.01``, ``1/125``, ``2.5s``: :func:`parse_time`), or
a file of them, one per frame (:func:`read_times`, ``--exposures times.txt``)."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError

__all__ = ["parse_time", "read_times"]


def parse_time(tok: str) -> float:
    """Parse an exposure time in seconds: ``0.01``, ``1/125``, ``2.5``. Raises ValueError for
    what is not a number; a time beyond float range reads as ``inf`` (``1e400/1``) or ``0.0``
    (``1/1e400``), which the callers refuse as not a positive finite time."""
    tok = tok.strip().rstrip("s")
    if "/" in tok:
        num, den = tok.split("/", 1)
        q = Fraction(num.strip()) / Fraction(den.strip())  # exact: no overflow on the way
        try:
            return float(q)
        except OverflowError:
            return float("inf") if q > 0 else float("-inf")
    return float(tok)


def read_times(path: Path, clip) -> tuple[np.ndarray, str]:
    """The exposure time (seconds) of each frame of ``clip`` from the file ``path``: one time per line
    (``0.01``, ``1/125``; ``#`` starts a comment), or a file name and its time per line (matched to the
    frames by name, else in file order); a file of the source's every frame is indexed by the
    frames taken. Returns ``(seconds (T,), how they were matched)``; one line when it cannot."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise LayercamError(f"cannot read exposure file {path}: {e.strerror or e}") from None
    named: list[tuple[str, float]] = []
    plain: list[float] = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        toks = line.replace(",", " ").split()
        try:
            plain.append(parse_time(toks[0]))
            val = plain[-1]
            name = None
        except (ValueError, ZeroDivisionError):
            name = toks[0]
            val = None
            for t in toks[1:]:
                try:
                    val = parse_time(t)
                    break
                except (ValueError, ZeroDivisionError):
                    continue
            if val is None:
                raise LayercamError(
                    f"{path.name} line {lineno}: no exposure time in {line[:60]!r}"
                ) from None
            named.append((name, val))
        if not (np.isfinite(val) and val > 0):
            raise LayercamError(f"{path.name} line {lineno}: an exposure time must be a positive "
                                f"finite number of seconds, got {toks[0 if name is None else 1]}")
    if named and plain:
        raise LayercamError(f"{path.name} mixes lines with and without file names")
    if not named and not plain:
        raise LayercamError(f"exposure file {path} lists no times")

    how = ""
    if named:
        table = {}
        for name, v in named:
            table[name] = v
            table[Path(name).stem] = v
        missing = [n for n in clip.names if n not in table]
        if not missing:
            secs = np.array([table[n] for n in clip.names], dtype=np.float64)
            how = " (matched by file name)"
        elif len(named) == clip.T:
            secs = np.array([v for _, v in named], dtype=np.float64)
            how = " (in file order; names did not match the frames)"
        else:
            raise LayercamError(
                f"exposure file {path.name} has no time for frame {missing[0]} ({len(named)} times for {clip.T} frames)"
            )
    else:
        vals = np.asarray(plain, dtype=np.float64)
        idx = clip.meta.get("frame_indices") if isinstance(clip.meta, dict) else None
        n_src = clip.meta.get("n_source_frames") if isinstance(clip.meta, dict) else None
        if len(vals) == clip.T:
            secs = vals
        elif (
            idx is not None
            and len(idx) == clip.T
            and len(vals) > max(idx)
            and (n_src is None or len(vals) == n_src)
        ):
            secs = vals[np.asarray(idx)]
            how = f" (selected {clip.T} of {len(vals)} by frame index)"
        else:
            expect = clip.T if n_src in (None, clip.T) else f"{clip.T} (or {n_src} source)"
            raise LayercamError(f"exposure file lists {len(vals)} times for {expect} frames")
    return secs, how
