"""The stage runner and its cache.

A stage's output lives in ``RUN/cache/<stage>-<key>/`` and is marked finished by ``done.json``.
The key hashes :data:`CACHE_VERSION`, the stage's name, the input (clip fingerprint and exposure
spec), the resolved settings the stage reads (``Stage.reads``: sections, ``section.field``s,
``static``, ``task``; :func:`settings_read`), and the keys of the stages it depends on. So the same command twice
skips finished stages; a changed setting redoes only the stages whose key it changes; and a stage
interrupted half-way finds its own folder again: training its checkpoint, an export its partial
outputs, which it removes and writes anew. Outputs for the top of the run folder are written here
too, and published as one set when every stage has finished (``pipelines/publish.py``).
"""

from __future__ import annotations

import errno
import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from layercam.core import heap
from layercam.engine import distributed
from layercam.core.config import Config, config_hash
from layercam.core.errors import LayercamError
from layercam.io.atomic import atomic_write, ensure_writable_dir
from layercam.io.clip import fingerprint

CACHE_VERSION = 19  # bumped when what a cached stage holds, or how a key is made, changes; older caches are made anew


@dataclass
class Context:
    """Everything a stage may read. ``results[name]``: each finished stage's typed result
    (:mod:`layercam.pipelines.results`: its summary and what later stages read)."""

    run_dir: Path
    clip: Any                       # layercam.io.Clip
    exposures: Any                  # layercam.io.Exposures
    cfg: Config                     # the settings as the user gave them (preset, --set, flags)
    task: str
    masks: Any = None               # (T, H, W) foreground masks or None
    progress: bool = True
    train_callbacks: list = field(default_factory=list)  # model -> trainer callback, besides the
                                                         # model's own (the bench's probe)
    measures: dict | None = None    # what the analysis measured (layercam.vision.analyse.measure)
    resolved: Any = None            # the run's settings, resolved once after the flow
                                    # (layercam.engine.resolve.Resolved)
    flow: Any = None                # the flow stage's arrays
                                    # (layercam.vision.flow_store.FlowArrays: on disk), opened once;
                                    # None for one frame
    model: Any = None               # the trained model (layercam.engine.model.ImplicitCameraModel), built once
    camera: dict | None = None      # a long clip's window after the first: the camera it holds
                                    # fixed (layercam.pipelines.windows)
    window: tuple | None = None     # a long clip's window: its frames [a, b) of the clip (its
                                    # export keeps its fit per pixel for the join)
    results: dict = field(default_factory=dict)   # stage name ->
                                                  # layercam.pipelines.results.StageResult (or its
                                                  # subclass)
    clip_levels: Any = None         # the clip's clipping levels (pipelines.stages.ctx_clip_levels), measured once
    ray: dict | None = None         # the Ray cluster a long clip's windows ran on
                                    # (layercam.pipelines.windows), None without --ray
    dirs: dict = field(default_factory=dict)
    keys: dict = field(default_factory=dict)
    times: dict = field(default_factory=dict)
    log: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    estimate: dict = field(default_factory=dict)  # what the run was estimated to cost
                                                  # (layercam.engine.estimate), before and after the
                                                  # analysis

    def say(self, msg: str) -> None:
        self.log.append(msg)
        if self.progress:
            print(msg, flush=True)

    def warn(self, msg: str) -> None:
        """Said on stderr even with ``--quiet`` (rank 0), and kept in the report's "warnings"."""
        self.warnings.append(msg)
        if distributed.is_main():
            print(f"warning: {msg}", file=sys.stderr, flush=True)

    def frames_bar(self, desc: str = "export"):
        """The clip's frame indices, with a progress bar when the run shows progress."""
        from layercam.core.progress import bar

        return bar(range(self.clip.T), desc=desc, unit="frame", enabled=self.progress)


class Stage:
    """A named, cached step. Subclasses set ``name``, ``deps``, ``reads`` (what of the resolved
    settings it reads, :func:`settings_read`) and implement :meth:`run` and optionally :meth:`load`.

    ``outputs``: the names this stage makes for the top of the run folder. It writes them into its
    own folder ``out``; what an interrupted attempt left there is removed before it runs again, and
    the finished set is published to the top when the run ends (``pipelines/publish.py``)."""

    name = "stage"
    deps: tuple = ()
    reads: tuple = ()
    outputs: tuple = ()

    def output_names(self, ctx: "Context") -> list[str]:
        """``outputs`` (a stage whose outputs depend on the task says so here)."""
        return list(self.outputs)

    def options(self, ctx: Context) -> dict:
        """What besides the settings the result depends on (a benchmark scorer's options); keyed."""
        return {}

    def run(self, ctx: Context, out: Path) -> dict:
        """Does the work into ``out``; returns the summary (JSON) its ``done.json`` keeps."""
        raise NotImplementedError

    def load(self, ctx: Context, out: Path, summary: dict):
        """The stage's typed result from its summary and folder (:mod:`layercam.pipelines.results`)."""
        from layercam.pipelines.results import StageResult

        return StageResult(summary)


def settings_read(ctx: Context, reads: tuple) -> dict:
    """The part of the run's settings ``reads`` names: a section (``"train"``: its keyed settings,
    :meth:`layercam.core.config.Config.key_dict`), one setting (``"scene.bootstrap"``), ``"static"``
    (:attr:`layercam.engine.resolve.Resolved.static`) or ``"task"``. Read from the resolved settings once
    the analysis has run, else (the flow) from those the user gave."""
    src = ctx.resolved.settings if ctx.resolved is not None else ctx.cfg
    out = {}
    for r in reads:
        if r == "static":
            out[r] = bool(ctx.resolved.static)
        elif r == "task":
            out[r] = ctx.task
        elif "." in r:
            sec, name = r.split(".")
            out[r] = getattr(getattr(src, sec), name)
        else:
            out[r] = src.key_dict(r)[r]
    return out


def input_key(ctx: Context) -> dict:
    e = ctx.exposures
    return {
        "clip": ctx.clip.fingerprint(),
        "exposures": {"log2_dt": [round(float(v), 6) for v in e.log2_dt], "learn": e.learn},
        # the masks' pixels, not their per-frame sums: a corrected mask covering as much elsewhere is new input
        "masks": None if ctx.masks is None else fingerprint(ctx.masks),
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
        material = {"cache": CACHE_VERSION, "stage": st.name, "input": inkey,
                    "settings": settings_read(ctx, st.reads), "options": st.options(ctx),
                    "deps": {d: ctx.keys[d] for d in st.deps}}
        key = config_hash(material)[:12]
        out = cache / f"{st.name}-{key}"
        ctx.keys[st.name], ctx.dirs[st.name] = key, out
        done = out / "done.json"
        alone = not getattr(st, "all_ranks", False)  # only data-parallel stages (training) run on every rank
        if alone and not main:
            distributed.barrier()  # until rank 0 has run this stage or found it cached
            if not done.exists():
                raise LayercamError(f"stage {st.name}: rank 0 did not leave a result in {out}")
        if done.exists() and main and not _outputs_kept(st.output_names(ctx), out, done):
            done.unlink()  # its outputs were removed from the cache: made again
        if done.exists():
            summary = json.loads(done.read_text())
            ctx.results[st.name] = st.load(ctx, out, summary)
            ctx.times[st.name] = {"seconds": 0.0, "cached": True,
                                  "original_seconds": summary.get("_seconds"),
                                  "original_cpu_seconds": summary.get("_cpu_seconds"),
                                  **({"original_peak_mb": summary["_peak_mb"]} if "_peak_mb" in summary else {})}
            ctx.say(f"[{st.name}] cached ({out.name})")
            if alone and main:
                distributed.barrier()
            continue
        t0, c0 = time.perf_counter(), time.process_time()
        heap.reset_peak()
        try:
            out.mkdir(parents=True, exist_ok=True)
            if main:
                (out / "settings.json").write_text(json.dumps(material, indent=1, default=str))
                _clear_outputs(st.output_names(ctx), out)  # an interrupted attempt's partial outputs
            summary = st.run(ctx, out)
        except OSError as e:  # a full disk where a stage writes without atomic_write (np.savez, ...)
            if e.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EROFS):
                raise
            raise LayercamError(f"[{st.name}] cannot write in {out}: {e.strerror}; free some space "
                                "and run the same command again: the finished stages are kept") from None
        secs, cpu = time.perf_counter() - t0, time.process_time() - c0
        peak = heap.peak_bytes()  # the stage's own peak resident memory
        summary["_seconds"], summary["_cpu_seconds"] = secs, cpu
        if peak:
            summary["_peak_mb"] = round(peak / 2**20, 1)
        summary["_outputs"] = [n for n in st.output_names(ctx) if (out / n).exists()]
        if main:
            atomic_write(done, lambda p: p.write_text(json.dumps(summary, indent=1, default=_json_default)))
        ctx.results[st.name] = st.load(ctx, out, summary)
        ctx.times[st.name] = {"seconds": round(secs, 3), "cpu_seconds": round(cpu, 3),
                              "cached": False, **({"peak_mb": summary["_peak_mb"]} if peak else {})}
        ctx.say(f"[{st.name}] done in {secs:.1f} s")
        if alone and main:
            distributed.barrier()
    return ctx


def _outputs_kept(outputs: list[str], out: Path, done: Path) -> bool:
    """A finished stage with outputs still holds them all in its folder."""
    if not outputs:
        return True
    names = json.loads(done.read_text()).get("_outputs")
    return names is not None and all((out / n).exists() for n in names)


def _clear_outputs(outputs: list[str], out: Path) -> None:
    for n in outputs:
        p = out / n
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


def output_sources(ctx: Context, stages: list[Stage]) -> tuple[dict, dict]:
    """The finished outputs of ``stages`` (name -> path in its stage's folder) and the keys of the
    stages that made them: the set to publish to the top of the run folder."""
    sources, keys = {}, {}
    for st in stages:
        if st.output_names(ctx) and st.name in ctx.dirs:
            keys[st.name] = ctx.keys[st.name]
            for n in st.output_names(ctx):
                if (ctx.dirs[st.name] / n).exists():
                    sources[n] = ctx.dirs[st.name] / n
    return sources, keys


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
