"""Per-frame exposure times from the user's ``--exposures`` spec (and the frames).

All ``log2_dt`` values are relative log2 exposure times (EV), **normalised so that their
minimum is 0** (the darkest frame/phase is 0). Only differences matter to the model.

Brightness measurements (used to find the brighter phase of ``alt``/``alt3`` and to initialise
learned exposures) linearise pixel values with a gamma of 2.2 and compare consecutive frames
pixel by pixel over pixels unclipped in both, so they are rough initial values, not calibration.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.io.clip import Clip
from layercam.io.times import read_times
from layercam.io.ev import _measure_phase_ev, _pair_diffs, _pairs_measured_per_pixel, check_ev_step, measure_pair_ev

__all__ = ["Exposures", "parse_exposures", "measure_pair_ev"]

_EV_MIN, _EV_MAX = 0.5, 12.0
MAX_SPAN_EV = 120.0  # exposures of one clip at most this many stops apart: 2^120 and the scene's
                     # own range within float32 (2^128)


@dataclass
class Exposures:
    """Exposure model for a clip of ``T`` frames.

    log2_dt: ``(T,)`` float32 initial relative log2 exposure time per frame, minimum 0.
    learn: ``"none"`` (times are given and fixed), ``"ratio"`` (one learned EV offset per
        phase; alt/alt3 without ev_step) or ``"all"`` (one learned value per frame, frame 0 fixed).
    phase: ``(T,)`` int phase index for alt/alt3/cycle specs (from the frame's index in the
        source, so stride is accounted for), else None.
    spec: the user's spec string (``"none"`` when None was given).
    reason: one line saying how the exposures were decided.
    dt_seconds: ``(T,)`` absolute exposure times in seconds when known (exif, file), else None.
    """

    log2_dt: np.ndarray
    learn: str
    phase: np.ndarray | None
    spec: str
    reason: str
    dt_seconds: np.ndarray | None = None
    warnings: list = field(default_factory=list)  # said once when the run starts

    def __post_init__(self) -> None:
        self.log2_dt = np.asarray(self.log2_dt, dtype=np.float32).reshape(-1)
        if self.learn not in ("none", "ratio", "all"):
            raise ValueError(f"learn must be none/ratio/all, got {self.learn!r}")
        if self.phase is not None:
            self.phase = np.asarray(self.phase, dtype=np.int64).reshape(-1)
            if self.phase.shape != self.log2_dt.shape:
                raise ValueError("phase and log2_dt must have the same length")
        if self.log2_dt.size and not np.isfinite(self.log2_dt).all():
            raise LayercamError(f"exposures ({self.spec}): an exposure is beyond the range of "
                                "numbers (check the times or EVs given)")
        if self.log2_dt.size and float(np.ptp(self.log2_dt)) > MAX_SPAN_EV:
            raise LayercamError(f"exposures ({self.spec}) span {float(np.ptp(self.log2_dt)):.3g} "
                                f"stops; at most {MAX_SPAN_EV:g} are supported (check the times or "
                                "EVs given)")

    @property
    def T(self) -> int:  # noqa: N802
        return int(self.log2_dt.shape[0])

    @property
    def count_distinct(self) -> int:
        """Number of distinct exposures (1 means a single exposure). Phases count when the
        spec has them; otherwise values are compared at a 0.1 EV tolerance."""
        if self.phase is not None and self.learn == "ratio":
            return int(len(np.unique(self.phase)))
        vals = np.sort(self.log2_dt.astype(np.float64))
        if vals.size == 0:
            return 0
        return int(1 + np.count_nonzero(np.diff(vals) > 0.1))

    @property
    def varies(self) -> bool:
        """The frames' exposures differ, given or to be learned (a sharp clip then has an HDR too)."""
        return self.count_distinct > 1 or self.learn != "none"


# ----------------------------------------------------------------------------- parsing helpers


def _frame_phase(clip: Clip, n: int) -> np.ndarray:
    idx = clip.meta.get("frame_indices") if isinstance(clip.meta, dict) else None
    if idx is None or len(idx) != clip.T:
        idx = range(clip.T)
    return np.asarray(idx, dtype=np.int64) % n


def _normalise(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return (v - v.min()).astype(np.float32)


def _fmt_phases(ev: np.ndarray) -> str:
    return ", ".join(f"{x:+.2f}" for x in ev)


# ----------------------------------------------------------------------------- specs


def _alt(clip: Clip, n: int, spec: str, ev_step: float | None, force_ev_step: bool = False) -> Exposures:
    if clip.T < n:
        raise LayercamError(f"'{spec}' needs at least {n} frames, the clip has {clip.T}")
    phase = _frame_phase(clip, n)
    present = np.unique(phase)
    if len(present) < n:
        stride = clip.meta.get("frame_indices", [0, 1])
        raise LayercamError(
            f"'{spec}': the selected frames cover only {len(present)} of {n} exposure phases "
            f"(frame indices {list(stride[:4])}...); use a stride that is not a multiple of {n}"
        )
    measured, stray = _measure_phase_ev(clip.frames, phase, n)  # EV per phase, phase 0 at 0
    if stray > _EV_MIN:  # frames of the same phases differ more than two exposures must: another cycle
        other = "alt3" if n == 2 else "alt"
        raise LayercamError(f"'{spec}': the frames do not repeat every {n} exposures (frames of "
                            f"the same phases differ by {stray:.1f} EV); "
                            f"try --exposures {other}, an EV cycle, or learn")
    order = np.argsort(measured)  # darkest first
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    gaps = np.diff(measured[order])
    small = bool(np.any(gaps < _EV_MIN))
    if n == 2:
        brighter = "odd" if order[1] == 1 else "even"
        what = f"alt: {brighter} frames brighter by {gaps[0]:.1f} EV (measured)"
    else:
        what = f"alt3: phases darkest..brightest {list(map(int, order))}, measured gaps " + ", ".join(
            f"{g:.1f}" for g in gaps
        ) + " EV"
    warning = ""
    if ev_step is not None:
        step = float(ev_step)
        warning = check_ev_step(step, gaps, _pairs_measured_per_pixel(clip.frames) >= 0.5, force_ev_step)
        per_phase = rank * step
        learn = "none"
        tail = f", ev-step {step:g} given" + (f" (warning: {warning})" if warning else "")
    else:
        clamped = np.clip(gaps, _EV_MIN, _EV_MAX)
        ranked = np.concatenate([[0.0], np.cumsum(clamped)])
        per_phase = ranked[rank]
        learn = "ratio"
        tail = ", ratio learned from initial " + "/".join(f"{g:.1f}" for g in clamped) + " EV"
    if small:
        tail += " (warning: phases differ by under 0.5 EV; is the clip really alternating?)"
    return Exposures(
        log2_dt=_normalise(per_phase[phase]),
        learn=learn,
        phase=phase,
        spec=spec,
        reason=what + tail,
        warnings=[warning] if warning else [],
    )


def _cycle(clip: Clip, spec: str, each: bool = False) -> Exposures:
    toks = [t for t in re.split(r"[,\s]+", spec.strip()) if t]
    evs = []
    for t in toks:
        try:
            v = float(t)
        except ValueError:
            raise LayercamError(
                f"exposure cycle entry {t!r} in {spec!r} is not a number (expected EVs like 0,3)"
            ) from None
        if not np.isfinite(v):
            raise LayercamError(f"exposure cycle entry {t!r} in {spec!r} is not finite")
        evs.append(v)
    if not evs:
        raise LayercamError(f"empty exposure cycle {spec!r}")
    n = len(evs)
    if each and 1 < n != clip.T:
        raise LayercamError(f"--exposures {spec!r} gives {n} EVs for {clip.T} images; a stack "
                            "needs one per image, in order")
    if n > clip.T:
        raise LayercamError(f"exposure cycle {spec!r} has {n} entries for {clip.T} frames (at most one per frame)")
    phase = _frame_phase(clip, n)
    log2 = np.asarray(evs, dtype=np.float64)[phase]
    return Exposures(
        log2_dt=_normalise(log2),
        learn="none",
        phase=phase,
        spec=spec,
        reason=f"cycle of {n} EV offsets ({', '.join(f'{v:g}' for v in evs)}) given, frame t uses entry t mod {n}",
    )


def _exif(clip: Clip, spec: str) -> Exposures:
    ex = clip.exif_exposures
    if ex is None:
        raise LayercamError(
            f"'exif' needs image files with EXIF exposure times; {clip.source} is not a set of images"
        )
    for name, v in zip(clip.names, ex):
        if v is None or not (v > 0):
            raise LayercamError(f"frame {name} has no EXIF exposure time; give --exposures FILE or learn")
    secs = np.asarray(ex, dtype=np.float64)
    return Exposures(
        log2_dt=_normalise(np.log2(secs)),
        learn="none",
        phase=None,
        spec=spec,
        reason=f"exif: {len(secs)} exposure times {_fmt_secs(secs)} from EXIF",
        dt_seconds=secs.astype(np.float32),
    )


def _fmt_secs(secs: np.ndarray) -> str:
    def one(s: float) -> str:
        return f"1/{1 / s:g}s" if s < 1 else f"{s:g}s"

    if len(secs) <= 4:
        return ", ".join(one(s) for s in secs)
    return f"{one(secs.min())}..{one(secs.max())}"


def _learn(clip: Clip, spec: str) -> Exposures:
    d = _pair_diffs(clip.frames) if clip.T > 1 else np.zeros(0)
    rel = np.concatenate([[0.0], np.cumsum(d)])
    return Exposures(
        log2_dt=_normalise(rel),
        learn="all",
        phase=None,
        spec=spec,
        reason=f"learn: one exposure per frame, initialised from measured brightness "
        f"(span {np.ptp(rel):.1f} EV), frame 0 fixed",
    )


def _read_time_file(path: Path, clip: Clip, spec: str) -> Exposures:
    secs, how = read_times(path, clip)
    return Exposures(
        log2_dt=_normalise(np.log2(secs)),
        learn="none",
        phase=None,
        spec=spec,
        reason=f"file {path.name}: {len(secs)} times {_fmt_secs(secs)}{how}",
        dt_seconds=secs.astype(np.float32),
    )


def parse_exposures(spec: str | None, clip: Clip, ev_step: float | None = None,
                    force_ev_step: bool = False, each: bool = False) -> Exposures:
    """Decide the exposure of each frame of ``clip`` from ``spec``.

    spec:
      ``None``/``"none"``/``"single"``: one exposure, all zeros.
      ``"alt"``/``"alt3"``: 2/3 alternating exposures; the brightness order of the phases is
          measured from the frames; phases get 0, ev_step, 2*ev_step (darkest first) when
          ``ev_step`` is given (learn="none"; checked against the measured gaps by
          :func:`check_ev_step`, ``force_ev_step`` skips the refusal), else measured gaps clamped to [0.5, 12] EV and
          learn="ratio".
      ``"0,3"``, ``"-2,0,2"``: explicit EV cycle, frame t uses entry t mod n (learn="none");
          with ``each`` (a photo stack, which has no cycle) a list must give one EV per frame.
      a text file: one exposure time per line in seconds (``0.01`` or ``1/125``; ``#``
          comments), or lines ``name time ...`` (e.g. ``DSC_0058.png 32 0.03125``) matched to
          frame names; a list covering the whole source is subset by frame index.
      ``"exif"``: EXIF times of the image files (all frames must have one).
      ``"learn"``: one learned exposure per frame, initialised from measured brightness.
    Returns ``Exposures`` with ``log2_dt`` of shape ``(T,)``, minimum 0. Bad specs raise
    ``LayercamError`` with one line.
    """
    if not isinstance(clip, Clip):
        raise TypeError(f"parse_exposures expects a Clip, got {type(clip).__name__}")
    if ev_step is not None:
        try:
            ev_step = float(ev_step)
        except (TypeError, ValueError):
            raise LayercamError(f"ev-step must be a number, got {ev_step!r}") from None
        if not np.isfinite(ev_step) or ev_step <= 0:
            raise LayercamError(f"ev-step must be positive, got {ev_step:g}")
    if spec is not None and not isinstance(spec, (str, os.PathLike)):
        raise LayercamError(f"bad exposure spec {spec!r}")
    s = "none" if spec is None else os.fspath(spec).strip()
    key = s.lower()
    if ev_step is not None and key not in ("alt", "alt3"):
        raise LayercamError(f"--ev-step is for --exposures alt or alt3; {s or 'none'!r} sets the exposures itself")
    if key in ("", "none", "single"):
        return Exposures(
            log2_dt=np.zeros(clip.T, np.float32),
            learn="none",
            phase=None,
            spec=s or "none",
            reason="single exposure: all frames share one exposure time",
        )
    if key == "alt":
        return _alt(clip, 2, s, ev_step, force_ev_step)
    if key == "alt3":
        return _alt(clip, 3, s, ev_step, force_ev_step)

    if key == "exif":
        return _exif(clip, s)
    if key == "learn":
        return _learn(clip, s)
    p = Path(s).expanduser()
    if p.is_file():
        return _read_time_file(p, clip, s)
    if p.is_dir():
        raise LayercamError(f"exposure spec {s!r} is a folder; expected a text file of times")
    if "," in s or re.fullmatch(r"[+-]?\d+(\.\d*)?", s):
        return _cycle(clip, s, each)
    if "/" in s or os.sep in s or p.suffix:
        raise LayercamError(f"exposure file not found: {s}")
    raise LayercamError(
        f"unknown exposure spec {s!r}: use none, alt, alt3, exif, learn, an EV cycle like 0,3, "
        "or a file of exposure times"
    )
