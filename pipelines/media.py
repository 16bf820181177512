"""What a run's outputs keep of the input's media: its frame rate, its sound and the bit depth of
its PNGs."""

from __future__ import annotations

from layercam.pipelines.runner import Context


def fps(ctx: Context) -> float:
    """The frame rate of every video a run writes: the input's (24 where it has none)."""
    return float(ctx.clip.fps or 24.0)


def audio(ctx: Context) -> dict | None:
    """The sound the run's videos carry over from the input (``clip.meta["audio"]``,
    :func:`layercam.io.inputs.audio_plan`); None without."""
    return ctx.clip.meta.get("audio")


def sound(ctx: Context, video) -> dict:
    """What became of the sound in ``video`` (a finished :class:`VideoWriter`), for the summary;
    a sound that could not be kept is said."""
    info = video.audio_info
    if info and not info["kept"]:
        ctx.warn(f"{video.path.name} is written without the input's sound: {info['why']}")
    elif info and info["why"]:
        ctx.say(f"[export] {video.path.name}: {info['why']}")
    return {video.path.name: info}


def png_bits(ctx: Context) -> int:
    """The bit depth of the PNGs a run writes: 16 for an input of more than 8 bits, else 8."""
    return 16 if ctx.clip.bit_depth > 8 else 8
