"""The stage runner and its cache.

A stage's output lives in ``RUN/cache/<stage>-<key>/`` and is marked finished by ``done.json``.
The key hashes the stage's name and version, the input (clip fingerprint and exposure spec), the
settings the stage reads, and the keys of the stages it depends on. So the same command twice
skips finished stages; a changed setting redoes only the stages whose key it changes; and a stage
interrupted half-way (training) finds its own partial state (a checkpoint) in the same folder.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from layercam import distributed
from layercam.config import Config, config_hash
from layercam.errors import LayercamError
from layercam.io.atomic import atomic_write, ensure_writable_dir


@dataclass
class Context:
    """Everything a stage may read. ``results[name]`` holds each finished stage's summary dict."""

    run_dir: Path
    clip: Any                       # layercam.io.Clip
    exposures: Any                  # layercam.io.Exposures
    cfg: Config                     # the model section and blur shape decided once the analysis has run
    task: str
    masks: Any = None               # (T, H, W) foreground masks or None
    progress: bool = True
    train_callbacks: list = field(default_factory=list)  # model -> trainer callback, besides the model's own (the bench's probe)
    measures: dict | None = None    # what the analysis measured (layercam.analyse.measure)
    reasons: dict = field(default_factory=dict)  # why the analysis decided each model setting
    flow: dict | None = None        # the flow stage's arrays (fw, bw, fw_ok, bw_ok, homs), read once
    model: Any = None               # the trained model (layercam.model.ImplicitCameraModel), built once
    results: dict = field(default_factory=dict)
    dirs: dict = field(default_factory=dict)
    keys: dict = field(default_factory=dict)
    times: dict = field(default_factory=dict)
    log: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    def say(self, msg: str) -> None:
        self.log.append(msg)
        if self.progress:
            print(msg, flush=True)

    def warn(self, msg: str) -> None:
        """Said on stderr even with ``--quiet`` (rank 0), and kept in the report's "warnings"."""
        self.warnings.append(msg)
        if distributed.is_main():
            print(f"warning: {msg}", file=sys.stderr, flush=True)


class Stage:
    """A named, cached step. Subclasses set ``name``, ``deps``, ``version`` and implement
    :meth:`key_material` (the settings it reads), :meth:`run` and optionally :meth:`load`."""

    name = "stage"
    deps: tuple = ()
    version = 1

    def key_material(self, ctx: Context) -> dict:
        return {}

    def run(self, ctx: Context, out: Path) -> dict:
        raise NotImplementedError

    def load(self, ctx: Context, out: Path, summary: dict) -> dict:
        return summary


def input_key(ctx: Context) -> dict:
    e = ctx.exposures
    return {
        "clip": ctx.clip.fingerprint(),
        "exposures": {"log2_dt": [round(float(v), 6) for v in e.log2_dt], "learn": e.learn},
        "masks": None if ctx.masks is None else config_hash(ctx.masks.sum(axis=(1, 2)).tolist()),
    }


def run_stages(ctx: Context, stages: list[Stage]) -> Context:
    ensure_writable_dir(ctx.run_dir)
    cache = ensure_writable_dir(ctx.run_dir / "cache")
    inkey = input_key(ctx)
    main = distributed.is_main()  # with torch.distributed: rank 0 runs a stage, the others read its result
    for st in stages:
        missing = [d for d in st.deps if d not in ctx.keys]
        if missing:
            raise RuntimeError(f"stage {st.name} needs {missing} first")
        material = {"stage": st.name, "version": st.version, "input": inkey, "settings": st.key_material(ctx), "deps": {d: ctx.keys[d] for d in st.deps}}
        key = config_hash(material)[:12]
        out = cache / f"{st.name}-{key}"
        ctx.keys[st.name], ctx.dirs[st.name] = key, out
        done = out / "done.json"
        alone = not getattr(st, "all_ranks", False)  # only data-parallel stages (training) run on every rank
        if alone and not main:
            distributed.barrier()  # until rank 0 has run this stage or found it cached
            if not done.exists():
                raise LayercamError(f"stage {st.name}: rank 0 did not leave a result in {out}")
        if done.exists():
            summary = json.loads(done.read_text())
            ctx.results[st.name] = st.load(ctx, out, summary)
            ctx.times[st.name] = {"seconds": 0.0, "cached": True, "original_seconds": summary.get("_seconds")}
            ctx.say(f"[{st.name}] cached ({out.name})")
            if alone and main:
                distributed.barrier()
            continue
        out.mkdir(parents=True, exist_ok=True)
        if main:
            (out / "settings.json").write_text(json.dumps(material, indent=1, default=str))
        t0 = time.perf_counter()
        summary = st.run(ctx, out)
        secs = time.perf_counter() - t0
        summary["_seconds"] = secs
        if main:
            atomic_write(done, lambda p: p.write_text(json.dumps(summary, indent=1, default=_json_default)))
        ctx.results[st.name] = st.load(ctx, out, summary)
        ctx.times[st.name] = {"seconds": round(secs, 3), "cached": False}
        ctx.say(f"[{st.name}] done in {secs:.1f} s")
        if alone and main:
            distributed.barrier()
    return ctx


def _json_default(o):
    try:
        import numpy as np

        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:  # pragma: no cover
        pass
    return str(o)


def write_json(path: Path, obj: Any) -> None:
    atomic_write(Path(path), lambda p: p.write_text(json.dumps(obj, indent=1, default=_json_default)))


def set_aside_previous(run_dir: Path, names: list[str], new_key: str, say) -> None:
    """If ``run_dir`` holds outputs of another export (other settings), move them to
    ``run_dir/previous/<old key>/`` instead of overwriting them."""
    marker = run_dir / "export_key.txt"
    if not marker.exists():
        leftovers = [n for n in names if (run_dir / n).exists()]
        if leftovers:
            raise LayercamError(f"{run_dir} already holds {leftovers[0]} from something else; choose another --out")
        return
    old = marker.read_text().strip()
    if old == new_key:
        return
    dest = run_dir / "previous" / old
    dest.mkdir(parents=True, exist_ok=True)
    for n in names + ["export_key.txt"]:
        src = run_dir / n
        if src.exists():
            shutil.move(str(src), str(dest / n))
    say(f"settings changed: earlier outputs moved to {dest}")
