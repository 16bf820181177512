"""Decide what the model for one clip contains. Every decision carries its reason and can be
forced by a flag (``overrides``)."""

from __future__ import annotations

from layercam.spec import ModelSpec

TASK_BLUR = {"hdr-video": "off", "deblur-video": "3x3", "fuse-stack": "3x3", "demo": "off"}


def decide(clip, exposures, task: str, overrides: dict | None = None, cfg=None) -> ModelSpec:
    """Choose layers, tone mapper, exposures, blur and flow loss for ``clip``.

    ``overrides`` maps ModelSpec field names to forced values (``None`` entries are ignored).
    """
    o = {k: v for k, v in (overrides or {}).items() if v is not None}
    spec = ModelSpec()
    r = spec.reasons
    spec.layers = 1
    r["layers"] = "default: one layer"
    n_exp = exposures.count_distinct
    learned = exposures.learn != "none"
    if n_exp > 1 or learned:
        spec.tone_mapper = "learned"
        r["tone_mapper"] = f"{n_exp} distinct exposures ({exposures.reason})"
    else:
        spec.tone_mapper = "fixed"
        r["tone_mapper"] = "a single exposure: no response curve can be learned, sRGB assumed"
    spec.exposures = "learned" if learned else "given"
    r["exposures"] = exposures.reason
    spec.blur = TASK_BLUR.get(task, "off")
    r["blur"] = f"task {task}"
    if cfg is not None:
        spec.max_offset = float(cfg.blur.max_offset)
    r["max_offset"] = "preset"
    spec.flow_loss = clip.T > 1
    r["flow_loss"] = "more than one frame" if spec.flow_loss else "a single frame has no neighbours"
    for k, v in o.items():
        setattr(spec, k, v)
        r[k] = f"forced by --{k.replace('_', '-')}"
    if spec.exposures == "learned" and exposures.learn == "none":
        spec.exposures = "given"
        r["exposures"] = "exposures were given; nothing to learn"
    return spec


def format_table(spec: ModelSpec) -> str:
    rows = [(k, str(getattr(spec, k)), spec.reasons.get(k, "")) for k in ("layers", "tone_mapper", "exposures", "blur", "max_offset", "flow_loss")]
    w0 = max(len(a) for a, _, _ in rows)
    w1 = max(len(b) for _, b, _ in rows)
    return "\n".join(f"  {a:<{w0}}  {b:<{w1}}  {c}" for a, b, c in rows)
