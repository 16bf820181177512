"""Presets: TOML files of the values that differ from the defaults (``configs/<name>.toml``, shipped
inside the package as ``layercam.configs``, or a path), then ``--set section.field=value`` items.

>>> cfg = load_config("fast", ["train.steps=50", "model.layers=2"])
>>> cfg.train.steps, cfg.model.layers, cfg.flow.method
(50, 2, 'dis_fast')
>>> load_config("fast", ["train.autocast=bogus"])
Traceback (most recent call last):
...
layercam.core.errors.LayercamError: train.autocast: expected one of auto, none, bf16, got 'bogus'
"""

from __future__ import annotations

import re
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from layercam.core.errors import LayercamError
from layercam.core.config import DEFAULT_PRESET, SECTIONS, Config, validate


def model_overrides(layers=None, tone_mapper=None, blur=None, max_offset=None, flow_loss=None) -> list[str]:
    """The model choices of the command-line flags (``--layers 2 --blur 3x3 --max-offset 2
    --flow-loss off``; ``None``: left to the analysis) as ``--set`` items."""
    out = []
    if layers is not None:
        out.append(f"model.layers={layers}")
    if tone_mapper is not None:
        out.append(f"model.tone_mapper={tone_mapper}")
    if blur is not None:
        if blur == "off":
            out.append("model.blur=off")
        else:
            m = re.fullmatch(r"(\d+)x\1", str(blur))
            if not m:
                raise LayercamError(f"blur must be off or NxN (3x3, 5x5), got {blur!r}")
            out += ["model.blur=on", f"blur.n={m.group(1)}"]
    if max_offset is not None:
        out.append(f"blur.max_offset={max_offset}")
    if flow_loss is not None:
        out.append(f"model.flow_loss={'on' if flow_loss in (True, 'on') else 'off'}")
    return out


# -- presets -------------------------------------------------------------------------------------
def preset_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("layercam.configs").iterdir() if p.name.endswith(".toml"))


def _read_preset(name: str) -> dict:
    path = Path(name)
    if path.suffix == ".toml" and path.exists():
        if not path.is_file():
            raise LayercamError(f"preset {name}: not a file (a preset is a name or a .toml file)")
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise LayercamError(f"preset {name}: not a text file (a preset is TOML)") from None
        except OSError as e:
            raise LayercamError(f"preset {name}: cannot read it ({e.strerror or e})") from None
    else:
        res = resources.files("layercam.configs").joinpath(f"{name}.toml")
        if not res.is_file():
            raise LayercamError(f"unknown preset {name!r} (built in: {', '.join(preset_names())}; or a .toml path)")
        text = res.read_text()
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise LayercamError(f"preset {name}: {e}") from None


def preset_tag(preset: str) -> str:
    """A preset's name for folders and tables: the file's stem for a ``.toml`` preset file."""
    return Path(preset).stem if preset.endswith(".toml") else preset


def load_config(preset: str = DEFAULT_PRESET, overrides: list[str] | None = None) -> Config:
    """Defaults, then the preset file's values, then each ``section.field=value`` override; checked."""
    cfg = Config(preset=preset_tag(preset))
    data = _read_preset(preset)
    for sec, values in data.items():
        if not isinstance(values, dict):
            raise LayercamError(f"preset {preset}: top-level key {sec!r} must be a [section]")
        for k, v in values.items():
            try:
                cfg.set(f"{sec}.{k}", v)
            except LayercamError as e:
                raise LayercamError(f"preset {preset}: {e}") from None
    for item in overrides or []:
        if "=" not in item:
            raise LayercamError(f"--set expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        cfg.set(k.strip(), v.strip())
    return validate(cfg)


def describe_settings() -> list[tuple[str, Any, str]]:
    """Every setting as ``(section.field, default, comment)``: the comment beside its field in
    :mod:`layercam.core.config` (what it trades; on any line of a field written over several),
    continued on the comment-only lines under it."""
    import ast
    import inspect

    out, defaults = [], Config()
    for sec in SECTIONS:
        section = getattr(defaults, sec)
        src = inspect.getsource(type(section)).splitlines()
        for n in ast.parse("\n".join(src)).body[0].body:
            if not isinstance(n, ast.AnnAssign):
                continue
            words = [src[i].split("#", 1)[1].strip() for i in range(n.lineno - 1, n.end_lineno) if "#" in src[i]]
            i = n.end_lineno - 1
            while i + 1 < len(src) and src[i + 1].strip().startswith("#"):
                i += 1
                words.append(src[i].strip()[1:].strip())
            out.append((f"{sec}.{n.target.id}", getattr(section, n.target.id), " ".join(words)))
    return out


def settings_help(width: int = 100) -> str:
    """The settings, for a command's ``--help``: ``section.field (default)`` and what it trades."""
    import textwrap

    rows = describe_settings()
    lines = [f"settings (--set section.field=VALUE; {len(rows)} in all; the defaults before a "
             "preset; a run's resolved values: report.json):"]
    for key, default, comment in rows:
        lines.append(f"  {key} = {default!r}")
        lines += textwrap.wrap(comment, width, initial_indent="      ", subsequent_indent="      ")
    return "\n".join(lines)
