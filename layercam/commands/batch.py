"""``layercam batch``: a list of jobs (one clip per line) processed unattended, and restartable.

Each job is the ordinary command line of another layercam command, run in its own process (so a
crash or an out-of-memory in one clip cannot take the others down, and ``--nproc`` works inside a
job). A job is finished when its run folder holds the ``report.json`` that this batch saw it write
(recorded, with the job, in ``<output>/batch_job.json``); finished jobs are skipped, so the same
batch can be started again after an interruption or a failure.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import io
import json
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from layercam.core.errors import LayercamError

MANIFEST_HELP = """manifest: a CSV file, one job per line (a header line is optional; lines starting with # are
comments):

  command,input,output,options
  hdr-video,clips/beach.mp4,runs/beach,--preset fast --ev-step 3
  hdr-video,clips/street/,runs/street,"--exposures times.txt --set train.steps=4000"
  demo,,runs/demo,--preset fast --steps 300

  command   a layercam command: hdr-video, demo, ...
  input     the clip (a video or a folder of frames); empty for a command without one
  output    the run folder (the command's --out); one job per folder
  options   the command's other options, written as on the command line (quote the field if it
            holds a comma); may be empty

Relative paths, also inside options, are relative to the manifest's folder: each job runs as
`python -m layercam COMMAND INPUT --out OUTPUT OPTIONS` in that folder, in a process of its own,
its output going to OUTPUT/batch.log.

Restarting: a job whose OUTPUT holds the report.json it wrote under this batch (recorded with the job
in OUTPUT/batch_job.json) is skipped. A job that failed, was interrupted (its training resumes from
the checkpoint) or whose options changed runs again; the command's stage cache then redoes only what
changed, and earlier outputs are moved to OUTPUT/previous/, never overwritten.

With --ray auto|ADDRESS the jobs run as tasks on a Ray cluster (pip install 'layercam[ray]'), each
asking for one GPU when the cluster has one, else one CPU, as many at once as it has room for;
auto: the cluster this machine belongs to, else one started here. The manifest's folder must be
reachable at the same path from every node (a shared file system; on one machine it is). Results
are said as jobs finish; the batch's folders, logs, skipping and exit status are as without it.

A line with an unclosed quote or options that do not parse fails (that line only). A failed job is
reported and the batch goes on to the next one. Exit status: 0 when every job finished or was
skipped, 1 when any job failed, 2 for an unreadable manifest or --summary path (checked before any
job runs)."""

JOB_FILE = "batch_job.json"
LOG_FILE = "batch.log"


@dataclass
class Job:
    line: int
    command: str
    input: str
    output: str
    options: list[str]
    status: str = "pending"   # pending | skipped | done | failed | would run | would skip
    reason: str = ""
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)

    def argv(self) -> list[str]:
        return [self.command] + ([self.input] if self.input else []) + ["--out", self.output] + self.options

    def signature(self) -> dict:
        return {"command": self.command, "input": self.input, "options": self.options}


def register(sub) -> argparse.ArgumentParser:
    b = sub.add_parser(
        "batch", help="run a manifest of jobs (one clip per line), skipping finished ones; restartable",
        description="Run many clips unattended: each line of MANIFEST is one layercam command on one clip.",
        epilog=MANIFEST_HELP, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    b.add_argument("manifest", help="CSV file: command,input,output,options (format below)")
    b.add_argument("--dry-run", action="store_true", help="list what would run and what would be skipped; run nothing")
    b.add_argument("--stop-on-error", action="store_true", help="stop at the first failed job (default: go on)")
    b.add_argument("--summary", metavar="FILE", help="also write the summary as JSON to FILE")
    b.add_argument("--ray", metavar="auto|ADDRESS",
                   help="run the jobs as tasks on a Ray cluster (one GPU each when it has GPUs, "
                        "else one CPU; auto: this machine's cluster, else one started here); "
                        "default: one after another")
    return b


def run(args) -> int:
    manifest = Path(args.manifest)
    jobs = read_manifest(manifest)
    if args.summary:
        check_summary_path(Path(args.summary))  # a bad path is found before any job runs
    base = manifest.resolve().parent
    print(f"batch {manifest}: {len(jobs)} job(s)", flush=True)
    if args.ray and not args.dry_run:
        return _run_on_ray(jobs, base, args)
    try:
        for i, job in enumerate(jobs, 1):
            head = f"[{i}/{len(jobs)}] {job.command} {job.input or '-'} -> {job.output}"
            if job.status == "failed":  # rejected while reading the manifest (bad options)
                print(f"{head}: FAILED: {job.reason}", flush=True)
            elif is_finished(job, base):
                job.status = "would skip" if args.dry_run else "skipped"
                print(f"{head}: finished earlier, skipped", flush=True)
            elif args.dry_run:
                job.status = "would run"
                print(f"{head}: would run", flush=True)
            else:
                print(f"{head}: running (log: {job.output}/{LOG_FILE})", flush=True)
                run_job(job, base)
                if job.status == "done":
                    print(f"{head}: done in {job.seconds:.0f} s", flush=True)
                else:
                    print(f"{head}: FAILED: {job.reason}", flush=True)
            if job.status == "failed" and args.stop_on_error:
                print("stopping at the first failure (--stop-on-error)", flush=True)
                break
    except KeyboardInterrupt:
        print("\ninterrupted: run the same batch again to go on (finished jobs are skipped)", file=sys.stderr)
        return 130
    return report(jobs, args.summary)


def _head(i: int, n: int, job: Job) -> str:
    return f"[{i}/{n}] {job.command} {job.input or '-'} -> {job.output}"


def _run_on_ray(jobs: list[Job], base: Path, args) -> int:
    """The jobs to run as Ray tasks (``layercam.engine.cluster``), reported as they finish."""
    from layercam.engine import cluster

    runner = cluster.Runner(args.ray)
    todo = []
    for i, job in enumerate(jobs, 1):
        head = _head(i, len(jobs), job)
        if job.status == "failed":
            print(f"{head}: FAILED: {job.reason}", flush=True)
        elif is_finished(job, base):
            job.status = "skipped"
            print(f"{head}: finished earlier, skipped", flush=True)
        else:
            todo.append((i, job))
            print(f"{head}: queued (log: {job.output}/{LOG_FILE})", flush=True)
    try:
        for n, (status, reason, seconds) in runner.as_completed(job_task, [(job, str(base)) for _, job in todo]):
            i, job = todo[n]
            job.status, job.reason, job.seconds = status, reason, seconds
            head = _head(i, len(jobs), job)
            print(f"{head}: done in {job.seconds:.0f} s" if status == "done"
                  else f"{head}: FAILED: {job.reason}", flush=True)
            if status == "failed" and args.stop_on_error:
                print("stopping at the first failure (--stop-on-error): the jobs still running are "
                      "cancelled", flush=True)
                break
    except KeyboardInterrupt:
        print("\ninterrupted: run the same batch again to go on (finished jobs are skipped)", file=sys.stderr)
        return 130
    return report(jobs, args.summary)


def job_task(item: tuple[Job, str]) -> tuple[str, str, float]:
    """A Ray task: one job, as :func:`run_job` runs it; ``(status, reason, seconds)``."""
    job, base = item
    run_job(job, Path(base))
    return job.status, job.reason, job.seconds


# -- the manifest ----------------------------------------------------------------------------------
def read_manifest(path: Path) -> list[Job]:
    """Jobs of the manifest at ``path``; a job with unreadable options is marked failed here."""
    if not path.is_file():
        raise LayercamError(f"manifest {path} not found")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise LayercamError(f"cannot read manifest {path}: {e}") from None
    commands = _command_names()
    jobs: list[Job] = []
    outputs: dict[str, int] = {}
    base = path.resolve().parent
    for n, line in enumerate(text.splitlines(), 1):  # line by line: a quote cannot swallow the next lines
        try:
            cells = [c.strip() for c in next(csv.reader([line], strict=True), [])]
        except csv.Error:
            guess = [c.strip() for c in line.split(",")] + ["", "", ""]
            jobs.append(Job(n, guess[0], guess[1], guess[2], [], "failed",
                            "unclosed quote in this line; close it (the line was not run)"))
            continue
        if not any(cells) or cells[0].startswith("#"):
            continue
        if not jobs and cells[0].lower() == "command":  # header
            continue
        if len(cells) < 3 or len(cells) > 4:
            raise LayercamError(f"{path} line {n}: expected command,input,output,options (got "
                                f"{len(cells)} fields; quote options that hold a comma)")
        command, inp, out = cells[:3]
        if command not in commands:
            raise LayercamError(f"{path} line {n}: unknown command {command!r} (one of {', '.join(sorted(commands))})")
        if not out:
            raise LayercamError(f"{path} line {n}: the output column (run folder) is empty")
        key = str((base / out).resolve())
        if key in outputs:
            raise LayercamError(f"{path} line {n}: run folder {out} is also the output of line {outputs[key]}")
        outputs[key] = n
        try:
            options = shlex.split(cells[3]) if len(cells) == 4 else []
        except ValueError as e:
            jobs.append(Job(n, command, inp, out, [], "failed", f"cannot split options: {e} (the line was not run)"))
            continue
        job = Job(n, command, inp, out, options)
        bad = _check_options(job)
        if bad:
            job.status, job.reason = "failed", bad
        jobs.append(job)
    if not jobs:
        raise LayercamError(f"{path}: no jobs (expected lines command,input,output,options)")
    return jobs


def _command_names() -> set[str]:
    from layercam.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return set(sub.choices) - {"batch"}


def _check_options(job: Job) -> str:
    """"" when the command line parses, else argparse's complaint."""
    from layercam.cli import build_parser

    if any(o == "--out" or o.startswith("--out=") for o in job.options):
        return "give the run folder in the output column, not as --out in options"
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(job.argv())
    except SystemExit:
        lines = [l for l in err.getvalue().strip().splitlines() if l.strip()]
        return "bad options: " + (lines[-1].removeprefix("error: ") if lines else " ".join(job.options))
    return ""


# -- running and skipping ---------------------------------------------------------------------------
def _sha1(path: Path) -> str:
    return hashlib.sha1(path.read_bytes()).hexdigest()


def is_finished(job: Job, base: Path) -> bool:
    """The run folder holds the report.json that this same job wrote under a batch."""
    out = base / job.output
    rep, rec = out / "report.json", out / JOB_FILE
    if not rep.is_file() or not rec.is_file():
        return False
    try:
        saved = json.loads(rec.read_text())
    except (OSError, ValueError):
        return False
    return saved.get("job") == job.signature() and saved.get("report_sha1") == _sha1(rep)


def run_job(job: Job, base: Path) -> None:
    from layercam.io.atomic import atomic_write

    out = base / job.output
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        job.status, job.reason = "failed", f"cannot create {job.output}: {e.strerror or e}"
        return
    (out / JOB_FILE).unlink(missing_ok=True)  # unfinished until this run says otherwise
    t0 = time.perf_counter()
    with open(out / LOG_FILE, "a", encoding="utf-8") as log:
        log.write(f"\n=== {time.strftime('%Y-%m-%d %H:%M:%S')}  layercam {shlex.join(job.argv())}\n")
        log.flush()
        proc = subprocess.Popen([sys.executable, "-m", "layercam", *job.argv()], cwd=base,
                                stdout=log, stderr=subprocess.STDOUT)
        try:
            code = proc.wait()
        except KeyboardInterrupt:  # the job got the Ctrl-C too: let it save its checkpoint
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            raise
    job.seconds = time.perf_counter() - t0
    rep = out / "report.json"
    if code != 0:
        job.status, job.reason = "failed", f"exit {code}: {_last_error(out / LOG_FILE)}"
    elif not rep.is_file():
        job.status, job.reason = "failed", "finished without writing report.json"
    else:
        job.status = "done"
        rec = {"job": job.signature(), "report_sha1": _sha1(rep),
               "finished": time.strftime("%Y-%m-%d %H:%M:%S"), "seconds": round(job.seconds, 1)}
        atomic_write(out / JOB_FILE, lambda p: p.write_text(json.dumps(rec, indent=1)))


def _last_error(log: Path) -> str:
    """The job's ``error: ...`` line (its last one), else its last line of output."""
    try:
        text = log.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return "no log"
    lines = [l.strip() for l in text.split("=== ")[-1].splitlines()[1:] if l.strip()]
    errors = [l for l in lines if l.startswith("error:")]
    return (errors or lines or ["no output"])[-1][:300]


def report(jobs: list[Job], summary_path: str | None) -> int:
    counts: dict[str, int] = {}
    for j in jobs:
        counts[j.status] = counts.get(j.status, 0) + 1
    order = ["done", "skipped", "failed", "would run", "would skip", "pending"]
    print("summary: " + ", ".join(f"{counts[k]} {k}" for k in order if counts.get(k)), flush=True)
    for j in jobs:
        if j.status == "failed":
            print(f"  failed: line {j.line} {j.command} {j.input or '-'} -> {j.output}: {j.reason}")
    code = 1 if counts.get("failed") else 0
    if summary_path:
        from layercam.io.atomic import atomic_write

        rows = [{"line": j.line, "command": j.command, "input": j.input, "output": j.output,
                 "options": j.options, "status": j.status, "reason": j.reason,
                 "seconds": round(j.seconds, 1)} for j in jobs]
        try:
            atomic_write(Path(summary_path),
                         lambda p: p.write_text(json.dumps({"counts": counts, "jobs": rows},
                                                           indent=1)))
        except (LayercamError, OSError) as e:  # said, but a failed job still decides the exit status
            print(f"error: cannot write the summary {summary_path}: "
                  f"{getattr(e, 'strerror', None) or e}", file=sys.stderr)
            code = code or 2
    return code


def check_summary_path(path: Path) -> None:
    """``--summary FILE`` can be written: not a folder, in a folder that exists or can be made and
    is writable. Raises ``LayercamError`` (one line)."""
    from layercam.io.atomic import ensure_writable_dir

    if path.is_dir():
        raise LayercamError(f"--summary {path} is a folder; give a file name")
    ensure_writable_dir(path.parent if str(path.parent) else Path("."))
