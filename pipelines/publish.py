"""The top of a run folder: one consistent set of outputs, replaced as a whole.

Stages that declare ``outputs`` (the export and atlas stages) write them into their own cache folder
(``RUN/cache/<stage>-<key>/``), where an interrupted stage is simply redone. When every stage has
finished, :func:`publish` makes the top of the run folder that set: the stages' outputs (hard links
to the cached files, copies where the file system has none) and ``report.json``, all from the same
settings, under one key (:func:`set_key`). ``RUN/outputs.json`` says which key and names the top
holds, and whether the set is complete; it is written before the first name is placed, so that a
command interrupted half-way through publishing (even by SIGKILL) is recognised and finished by the
next one.

A set from other settings is moved to ``RUN/previous/<its key>/`` (never overwritten); switching
back to earlier settings publishes their outputs again from the cache (or, when the cache lost them,
the stage is redone). ``render/`` and ``edit/``, made from the set's checkpoint, move with it and
come back with it. Files at the top that no ``outputs.json`` explains belong to something else: the
run refuses to start (:func:`check_folder`); run folders of earlier versions (``export_key.txt``,
or a ``cache/`` next to unmarked outputs) are set aside like any other set.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from layercam.core.config import config_hash
from layercam.core.errors import LayercamError
from layercam.core.interrupts import deferred, reached
from layercam.io.atomic import atomic_write, replace_entry
from layercam.pipelines.runner import write_json

MANIFEST = "outputs.json"
REPORT = "report.json"
DERIVED = ("render", "edit")  # made from the set's checkpoint by `layercam render` / `layercam edit`
LEGACY_KEY = "export_key.txt"  # what runs of earlier versions marked their top level with


def set_key(stage_keys: dict) -> str:
    """The key of a published set: its output stages' cache keys, together."""
    return config_hash(stage_keys)[:12]


def read_manifest(run: Path) -> dict | None:
    """What the top of ``run`` holds: ``{"key", "names", "complete", ...}``; for a run folder of an
    earlier version (marked by ``export_key.txt``) its outputs as a complete set; None for none."""
    try:
        m = json.loads((run / MANIFEST).read_text())
    except FileNotFoundError:
        m = None
    except (OSError, ValueError):
        raise LayercamError(f"{run / MANIFEST} is unreadable; move it away (the outputs it describes stay)") from None
    else:
        if not _manifest_ok(m):
            raise LayercamError(f"{run / MANIFEST} is not a layercam outputs list (corrupt?); move "
                                "it away (the outputs it describes stay)")
        return m
    from layercam.pipelines.export import all_output_names

    names = [n for n in all_output_names() + [REPORT, LEGACY_KEY] if (run / n).exists()]
    legacy = run / LEGACY_KEY
    if legacy.is_file():
        return {"key": legacy.read_text().strip() or "earlier", "names": names, "complete": True}
    if names and (run / "cache").is_dir():  # an earlier version's run, interrupted while exporting
        return {"key": "unmarked-" + time.strftime("%Y%m%d-%H%M%S"), "names": names, "complete": True}
    return None


def _manifest_ok(m) -> bool:
    """``m`` has the shape :func:`publish` writes: a dict with a text ``key``, a list of plain
    names (no path separators, not ``..``) and, when present, a bool ``complete``."""
    def plain(n) -> bool:
        return isinstance(n, str) and n not in ("", ".", "..") and "/" not in n and "\\" not in n

    if not isinstance(m, dict) or not plain(m.get("key")) or not isinstance(m.get("names"),
                      list) or not all(plain(n) for n in m["names"]):
        return False
    return isinstance(m.get("complete", False), bool) and isinstance(m.get("stages", {}), dict)


def check_folder(run: Path, names: list[str]) -> None:
    """Refuses (one line) a run folder whose top holds any of ``names`` that no ``outputs.json``
    explains: files of something else, not to be overwritten or moved."""
    if read_manifest(run) is not None:
        return
    for n in names + [REPORT]:
        if (run / n).exists():
            raise LayercamError(f"{run} already holds {n} from something else; choose another --out")


def _write_manifest(run: Path, m: dict) -> None:
    atomic_write(run / MANIFEST, lambda p: p.write_text(json.dumps(m, indent=1)))


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:  # no hard links here (another file system, FAT, some network shares)
        shutil.copy2(src, dst)


def _place(src: Path, dst: Path) -> None:
    """``dst`` becomes a copy of ``src`` (file or folder; hard links where possible), in one rename."""
    if dst.is_file() and src.is_file() and os.path.samefile(src, dst):
        return  # already this file (a rename onto its own hard link would do nothing, leaving tmp)
    tmp = dst.with_name(f".publishing-{dst.name}")
    if tmp.is_dir():
        shutil.rmtree(tmp)
    tmp.unlink(missing_ok=True)
    if src.is_dir():
        shutil.copytree(src, tmp, copy_function=_link_or_copy)
    else:
        _link_or_copy(str(src), str(tmp))
    replace_entry(tmp, dst)


def _set_aside(run: Path, m: dict, say) -> None:
    """Moves the complete set ``m`` (and what was made from it) to ``previous/<key>/``."""
    dest = run / "previous" / m["key"]
    dest.mkdir(parents=True, exist_ok=True)
    _write_manifest(dest, m)
    moved = False
    for n in list(m["names"]) + [LEGACY_KEY, *DERIVED]:
        if (run / n).exists():
            if (dest / n).exists():  # kept from an earlier switch: the newer copy replaces it
                replace_entry(run / n, dest / n)
            else:
                os.rename(run / n, dest / n)
            moved = True
    if moved:
        say(f"the input, the settings or layercam's cache version changed: earlier outputs moved to {dest}")


def publish(run: Path, sources: dict[str, Path], report: dict, key: str, say=print) -> None:
    """Makes the top of ``run`` the set ``sources`` (name -> finished file or folder in a stage's
    cache folder) plus ``report.json`` (from ``report``), under ``key``. Ctrl-C waits until the set
    is whole; after SIGKILL the next call finishes (or replaces) the half-published set."""
    names = list(sources) + [REPORT]
    with deferred():
        m = read_manifest(run)
        if m is not None and m["key"] != key:
            if m.get("complete"):
                _set_aside(run, m, say)
            else:  # an interrupted publish of other settings: copies of cached files, dropped
                for n in m["names"]:
                    if (run / n).is_dir():
                        shutil.rmtree(run / n)
                    elif (run / n).exists():
                        (run / n).unlink()
            m = None
        whole = m is not None and m.get("complete") and m["names"] == names and all((run / n).exists() for n in names)
        if not whole:
            _write_manifest(run, {"key": key, "names": names, "complete": False})
            for i, (n, src) in enumerate(sources.items()):
                reached("publish", i)
                _place(src, run / n)
        write_json(run / REPORT, report)
        for d in DERIVED:  # made from this set earlier, set aside when other settings took the top
            kept = run / "previous" / key / d
            if kept.exists() and not (run / d).exists():
                os.rename(kept, run / d)
        _write_manifest(run, {"key": key, "names": names, "complete": True, "stages": report.get("cache_keys", {})})
