"""``layercam bench --table length``: what a run costs as the clip grows longer.

A real clip (a DAVIS clip from the shared captures) is played forth and back to ``T`` frames and
written as an H.264 mp4 (:func:`long_clip`); then ``layercam hdr-video`` runs on it as a user would,
in its own process as a user runs it, while a thread of the bench's samples that process's memory
(:class:`MemorySampler`: resident set from ``/proc/PID/status``, with its anonymous part, every
50 ms) and the run reports each stage's peak (the kernel's high-water mark). Recorded per length:
peak resident memory (and its anonymous part), the estimate the run printed before the work, wall
time and seconds and peak memory per stage. Writes ``length.csv``, ``length.json`` and ``length.png``
(peak memory and wall time against ``T``) after each case; a later run into the same folder replaces
the rows of the lengths it runs and keeps the others.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path


from layercam.core.errors import LayercamError
from layercam.core.heap import proc_status

LENGTHS = [48, 192, 768]
FIELDS = ["clip", "frames", "size", "preset", "layers", "steps", "wall_s", "cpu_s", "flow_s",
          "bootstrap_s", "train_s", "export_s",
          "peak_rss_mb", "peak_anon_mb", "estimate_mb", "estimate_disk_mb", "cache_mb", "note"]
          # and stage_peak_mb, stage_cpu_s in length.json


class MemorySampler:
    """A thread that reads the resident memory of process ``pid`` (default this one) every ``every``
    seconds: ``peak`` (the largest ``VmRSS``), ``peak_anon`` (the largest anonymous part: what the
    process allocated, without the pages of files it maps, which the kernel can drop) and
    ``series`` ``[(seconds, rss, anon), ...]`` (a reading a second).

    >>> with MemorySampler(proc.pid) as m:       # doctest: +SKIP
    ...     proc.wait()
    >>> m.peak, m.peak_anon                      # doctest: +SKIP
    """

    def __init__(self, pid: int | str = "self", every: float = 0.05):
        self.pid, self.every, self.series, self.peak, self.peak_anon = pid, every, [], 0.0, 0.0
        self._stop = threading.Event()
        self._t0 = time.perf_counter()

    def _read(self) -> None:
        s = {k: v / 1024.0 for k, v in proc_status(self.pid).items()}  # MB
        if not s:
            return
        self.peak = max(self.peak, s.get("VmRSS", 0.0))
        self.peak_anon = max(self.peak_anon, s.get("RssAnon", 0.0))
        if not self.series or time.perf_counter() - self._t0 - self.series[-1][0] >= 1.0:
            # a reading a second for the record
            self.series.append((round(time.perf_counter() - self._t0, 2),
                                round(s.get("VmRSS", 0.0), 1), round(s.get("RssAnon", 0.0), 1)))

    def _loop(self) -> None:
        while not self._stop.wait(self.every):
            self._read()

    def __enter__(self) -> "MemorySampler":
        self._read()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def long_clip(frames_dir: Path, n: int, out: Path, size: tuple[int, int] | None = None, fps: float = 30.0) -> Path:
    """An mp4 of ``n`` frames: the images of ``frames_dir`` (sorted by name) played forth and back
    (0, 1, .., K-1, K-2, .., 1, 0, 1, ..), resized to ``size = (W, H)`` when given (bicubic), H.264
    at x264's visually lossless quality. Skipped when ``out`` exists (its name should say n and size)."""
    import cv2

    from layercam.io import VideoWriter
    from layercam.io.inputs import natural_key

    out = Path(out)
    if out.exists():
        return out
    paths = sorted((p for p in Path(frames_dir).iterdir()
                    if p.suffix.lower() in (".jpg", ".jpeg", ".png")),
                   key=lambda p: natural_key(p.name))
    if len(paths) < 2:
        raise LayercamError(f"{frames_dir}: needs at least two frames to build a long clip")
    cycle = list(range(len(paths))) + list(range(len(paths) - 2, 0, -1))
    out.parent.mkdir(parents=True, exist_ok=True)
    with VideoWriter(out, fps=fps) as vw:
        for i in range(n):
            img = cv2.cvtColor(cv2.imread(str(paths[cycle[i % len(cycle)]])), cv2.COLOR_BGR2RGB)
            if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
                img = cv2.resize(img, tuple(size), interpolation=cv2.INTER_CUBIC)
            vw.add(img)
    return out


def long_masks(masks_dir: Path, n: int, out: Path, size: tuple[int, int] | None = None) -> Path:
    """The masks of ``masks_dir`` played forth and back as :func:`long_clip` plays its frames: a
    folder of ``n`` PNGs (nearest-neighbour resized to ``size = (W, H)``), for ``--masks``."""
    import cv2

    from layercam.io.inputs import natural_key

    out = Path(out)
    if out.is_dir() and len(list(out.glob("*.png"))) == n:
        return out
    paths = sorted((p for p in Path(masks_dir).iterdir() if p.suffix.lower() == ".png"),
                   key=lambda p: natural_key(p.name))
    cycle = list(range(len(paths))) + list(range(len(paths) - 2, 0, -1))
    out.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        m = cv2.imread(str(paths[cycle[i % len(cycle)]]), cv2.IMREAD_UNCHANGED)
        if size is not None and (m.shape[1], m.shape[0]) != tuple(size):
            m = cv2.resize(m, tuple(size), interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(out / f"{i:05d}.png"), m)
    return out


# -- the job, in its own process ------------------------------------------------------------------
def _spawn(job: dict) -> dict:
    """``layercam hdr-video`` on the clip as a user runs it (``python -m layercam``, torch's threads
    set by ``OMP_NUM_THREADS``), its memory sampled from this process (no thread of the bench's in
    the run's process, whose heap it would change). The peak is the one the run reports
    (``report.json``: the kernel's high-water mark up to the report, across its stages; not the
    shared libraries the interpreter pages in as it exits, which the readings see), the readings'
    largest where it reports none (a run stopped on purpose); each stage's peak is the run's own
    (``peak_mb`` of each stage, the largest over windows)."""
    argv = [sys.executable, "-m", "layercam", "hdr-video", job["clip"], "--exposures", "none",
            "--preset", job["preset"], "--out", job["out"], "--quiet"]
    if job.get("masks"):
        argv += ["--masks", job["masks"]]
    for s in job["overrides"]:
        argv += ["--set", s]
    env = {**os.environ, "OMP_NUM_THREADS": str(job["threads"])}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    with MemorySampler(p.pid) as mem:
        err = p.communicate()[1]
    wall = time.perf_counter() - t0
    use = resource.getrusage(resource.RUSAGE_CHILDREN)  # the run and its decoder's ffmpeg, once waited for
    # stopped on purpose (a partial run)
    stopped = os.environ.get("LAYERCAM_SIGNAL_AT") if p.returncode == 130 else None
    if p.returncode != 0 and not stopped:
        tail = (err or "").strip().splitlines()[-1:] or [f"exit {p.returncode}"]
        raise LayercamError(f"length job {job['frames']} frames failed: {tail[0]}")
    rep_path = Path(job["out"], "report.json")
    rep = json.loads(rep_path.read_text()) if rep_path.exists() and not stopped else {}
    reported = (rep.get("memory", {}).get("peak_rss_bytes") or 0) / 2**20
    stages: dict = {}
    for times in [rep.get("stages", {})] + [r.get("times", {}) for r in rep.get("windows", {}).get("runs", [])]:
        for k, v in times.items():
            peak = v.get("peak_mb") or v.get("original_peak_mb")  # a resumed run: the peak its stage had when it ran
            if peak:
                stages[k] = max(stages.get(k, 0.0), peak)
    res = {"wall_s": round(wall, 2),
           "cpu_s": round(use.ru_utime + use.ru_stime - before.ru_utime - before.ru_stime, 1),
           "peak_rss_mb": round(reported or mem.peak, 1),
           "peak_anon_mb": round(mem.peak_anon, 1), "stage_peak_mb": stages,
           **({"stopped_at": stopped} if stopped else {})}
    Path(job["out"]).mkdir(parents=True, exist_ok=True)
    Path(job["out"], "memory.json").write_text(json.dumps({**res, "series": mem.series}))
    return res


def _row(clip: str, n: int, size: tuple[int, int], preset: str, run: Path, res: dict, note: str) -> dict:
    from layercam.engine.estimate import disk_used

    rep = json.loads((run / "report.json").read_text())
    st = rep["stages"]
    sec = lambda k: round(st.get(k, {}).get("seconds", 0.0), 1)  # noqa: E731
    est = rep.get("memory", {}).get("estimate", {}).get("before", {})
    return {"clip": clip, "frames": n, "size": f"{size[0]}x{size[1]}", "preset": preset,
            "layers": rep["analysis"].get("layers"),
            "steps": rep["train"].get("steps"), "wall_s": res["wall_s"], "cpu_s": res.get("cpu_s"),
            "flow_s": sec("flow"), "bootstrap_s": sec("bootstrap"),
            "train_s": sec("train"), "export_s": sec("export"), "peak_rss_mb": res["peak_rss_mb"],
            "peak_anon_mb": res["peak_anon_mb"],
            "estimate_mb": round(est.get("memory", 0) / 2**20),
            "estimate_disk_mb": round(est.get("disk", 0) / 2**20),  # MiB, as the peaks
            "cache_mb": round(disk_used(run / "cache") / 2**20), "stage_peak_mb": res.get("stage_peak_mb", {}),
            "stage_cpu_s": {k: v.get("cpu_seconds") for k, v in st.items() if "cpu_seconds" in v}, "note": note}


def run_length(out: Path, data: Path, clip: str = "cows", lengths: list[int] | None = None,
               preset: str = "fast", size: tuple[int, int] | None = None,
               threads: int = 1, overrides: list[str] | None = None, progress: bool = True,
               masks: bool = False) -> list[dict]:
    """The table: for each length of ``lengths`` (default 48, 192, 768) the DAVIS clip ``clip``
    played forth and back (:func:`long_clip`, at ``size`` ``(W, H)`` or its own), ``layercam
    hdr-video --exposures none --preset PRESET`` on it in its own process, one at a time; with
    ``masks``, its true masks played alike given as ``--masks`` (no motion segmentation)."""
    from layercam.io.atomic import ensure_writable_dir

    out = ensure_writable_dir(Path(out))
    say = print if progress else (lambda *a, **k: None)
    frames_dir = Path(data) / f"layers_davis_{clip}" / "frames"
    if not frames_dir.is_dir():
        raise LayercamError(f"no DAVIS clip {clip!r} in {data} (expected {frames_dir})")
    rows = json.loads((out / "length.json").read_text()) if (out / "length.json").exists() else []
    for n in lengths or LENGTHS:
        tag = f"{clip}-{n}" + (f"-{size[0]}x{size[1]}" if size else "")
        video = long_clip(frames_dir, n, out / "clips" / f"{tag}.mp4", size)
        job = {"clip": str(video), "preset": preset, "threads": threads,
               "overrides": list(overrides or []), "frames": n}
        if masks:
            job["masks"] = str(long_masks(frames_dir.parent / "masks_gt", n, out / "clips" / f"{tag}-masks", size))
            tag += "-masks"
        run = out / "runs" / f"{tag}-{preset}"
        res = _spawn({**job, "out": str(run)})
        from layercam.io.video import probe_video

        row = _row(clip + (" (true masks given)" if masks else ""), n, probe_video(video)["size"],
                   preset, run, res, f"{threads} thread(s); " + " ".join(overrides or []))
        rows = [r for r in rows
                if (r["clip"], r["frames"], r["size"], r["preset"]) != (row["clip"], row["frames"],
                    row["size"], row["preset"])] + [row]
        rows.sort(key=lambda r: (r["size"], r["preset"], r["frames"]))
        write_length(out, rows)
        say(f"{tag:>16} {preset}: {row['wall_s']:8.1f} s, peak {row['peak_rss_mb']:.0f} MiB "
            f"(anonymous {row['peak_anon_mb']:.0f}), estimate {row['estimate_mb']} MiB")
    return rows


def write_length(out: Path, rows: list[dict]) -> None:
    from layercam.bench.synthetic import write_csv
    from layercam.io.atomic import atomic_write

    write_csv(out / "length.csv", rows, FIELDS)
    atomic_write(out / "length.json", lambda p: p.write_text(json.dumps(rows, indent=1)))
    plot_length(out / "length.png", rows)


def plot_length(path: Path, rows: list[dict]) -> None:
    """Two panels against the clip's length: peak memory (resident, its anonymous part, the
    estimate said before the work) and time, wall and CPU (with the line through the origin and the
    shortest clip: time proportional to the length)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from layercam.engine.estimate import MIB
    from layercam.io.atomic import atomic_write

    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6), dpi=110)
    for i, key in enumerate(sorted({(r["size"], r["preset"]) for r in rows})):
        pts = sorted((r for r in rows if (r["size"], r["preset"]) == key), key=lambda r: r["frames"])
        x = [r["frames"] for r in pts]
        c = f"C{i}"
        gb = lambda k: [r[k] * MIB / 1000 for r in pts]  # noqa: E731 - the columns are MiB; the
                                                         # axis GB of 1e9 B, as the README
        a.plot(x, gb("peak_rss_mb"), "o-", color=c, label=f"{key[0]} {key[1]}: peak resident")
        a.plot(x, gb("peak_anon_mb"), "s:", color=c, label="its anonymous part")
        a.plot(x, gb("estimate_mb"), "x--", color=c, label="estimate before the work")
        b.plot(x, [r["wall_s"] / 60 for r in pts], "o-", color=c, label=f"{key[0]} {key[1]}: wall")
        if all(r.get("cpu_s") for r in pts):
            b.plot(x, [r["cpu_s"] / 60 for r in pts], "s:", color=c, label="CPU (all threads)")
        if x:
            b.plot([0, max(x)], [0, pts[0]["wall_s"] / 60 * max(x) / x[0]], ":", color="grey",
                   label="proportional to the length")
    for ax, title in ((a, "peak memory (GB)"), (b, "time (min)")):
        ax.set_xscale("log", base=2)
        ax.set_xticks(sorted({r["frames"] for r in rows}), [str(v) for v in sorted({r["frames"] for r in rows})])
        ax.set_xlabel("frames")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    a.set_ylim(bottom=0)
    b.set_xscale("linear")
    b.set_xlim(left=0)
    b.set_ylim(bottom=0)
    fig.suptitle("layercam: cost against the clip's length (a DAVIS clip played forth and back)", fontsize=10)
    fig.tight_layout()
    atomic_write(Path(path), lambda p: fig.savefig(p))
    plt.close(fig)
