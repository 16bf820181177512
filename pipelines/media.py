"""What the export's writers read of a run's context: the frames' range with a progress bar, the
frame rate, the sound, the bit depth of the PNGs, whether exposures vary, and a stack's reference view."""

from __future__ import annotations

from layercam.core.errors import LayercamError
from layercam.pipelines.runner import Context


def exposures_vary(ctx: Context) -> bool:
    return ctx.exposures.count_distinct > 1 or ctx.exposures.learn != "none"


def resolve_reference(ref, n: int) -> int:
    """The image a stack is fused into (``export.reference``): "middle" (default,
    :func:`layercam.core.geometry.middle_frame`), "first", "last" or an index (negative counts from the
    end) among ``n`` images."""
    from layercam.core.geometry import middle_frame

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


def _frames(ctx: Context, desc: str = "export"):
    from layercam.core.progress import bar

    return bar(range(ctx.clip.T), desc=desc, unit="frame", enabled=ctx.progress)


def _fps(ctx: Context) -> float:
    return float(ctx.clip.fps or 24.0)


def audio(ctx: Context) -> dict | None:
    """The sound the run's videos carry over from the input (``clip.meta["audio"]``,
    :func:`layercam.io.inputs.audio_plan`); None without."""
    return ctx.clip.meta.get("audio")


def _sound(ctx: Context, video) -> dict:
    """What became of the sound in ``video`` (a finished :class:`VideoWriter`), for the summary;
    a sound that could not be kept is said."""
    info = video.audio_info
    if info and not info["kept"]:
        ctx.warn(f"{video.path.name} is written without the input's sound: {info['why']}")
    elif info and info["why"]:
        ctx.say(f"[export] {video.path.name}: {info['why']}")
    return {video.path.name: info}


def _bits(ctx: Context) -> int:
    return 16 if ctx.clip.bit_depth > 8 else 8
