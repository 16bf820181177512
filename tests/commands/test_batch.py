"""``layercam batch``: runs a manifest, goes on past a failed job, skips finished jobs when restarted,
and runs again the job whose options changed."""

from __future__ import annotations

import json

import pytest

from layercam.cli import main

from conftest import TINY


@pytest.fixture
def clips(tmp_path):
    from layercam import synth
    from layercam.io import write_png

    for name, seed in (("a", 1), ("b", 2)):
        sc = synth.pan_hdr(frames=4, size=(32, 32), ev_step=3.0, seed=seed)
        (tmp_path / "clips" / name).mkdir(parents=True)
        for t, f in enumerate(sc.clip.frames):
            write_png(tmp_path / "clips" / name / f"f{t}.png", f)
    return tmp_path


def _manifest(folder, b_extra: str = "") -> None:
    opts = "--ev-step 3 --preset fast --quiet " + " ".join(f"--set {s}" for s in TINY)
    (folder / "jobs.csv").write_text(
        "command,input,output,options\n"
        "# two clips and one that does not exist\n"
        f"hdr-video,clips/a,runs/a,{opts}\n"
        f'hdr-video,clips/b,runs/b,"{opts} {b_extra}"\n'
        f"hdr-video,clips/missing,runs/missing,{opts}\n"
    )


def test_batch_runs_skips_and_restarts(clips, capsys, monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # the jobs are processes of their own; one thread each is plenty here
    _manifest(clips)
    summary = clips / "summary.json"
    assert main(["batch", str(clips / "jobs.csv"), "--summary", str(summary)]) == 1  # one job failed
    out = capsys.readouterr().out
    assert "2 done, 1 failed" in out, out
    for name in ("a", "b"):
        run = clips / "runs" / name
        log = (run / "batch.log").read_text() if (run / "batch.log").exists() else "no log"
        assert (run / "report.json").is_file() and (run / "batch_job.json").is_file(), log[-3000:]
        assert len(list((run / "hdr").glob("*.exr"))) == 4
    rows = {r["output"]: r for r in json.loads(summary.read_text())["jobs"]}
    assert rows["runs/missing"]["status"] == "failed" and "missing" in rows["runs/missing"]["reason"]

    # restarted: the finished jobs are skipped, the failed one is tried again
    stamp = {n: (clips / "runs" / n / "report.json").stat().st_mtime_ns for n in ("a", "b")}
    assert main(["batch", str(clips / "jobs.csv")]) == 1
    out = capsys.readouterr().out
    assert "2 skipped, 1 failed" in out, out
    assert {n: (clips / "runs" / n / "report.json").stat().st_mtime_ns for n in ("a", "b")} == stamp

    # job b's options change (an export setting): b runs again, from its cached training; a is skipped
    _manifest(clips, "--set export.half=false")
    assert main(["batch", str(clips / "jobs.csv"), "--dry-run"]) == 0
    assert "2 would run, 1 would skip" in capsys.readouterr().out
    assert main(["batch", str(clips / "jobs.csv")]) == 1
    out = capsys.readouterr().out
    assert "1 done, 1 skipped, 1 failed" in out, out
    rep = json.loads((clips / "runs" / "b" / "report.json").read_text())
    assert rep["stages"]["train"]["cached"] and not rep["stages"]["export"]["cached"]


def test_bad_manifest_is_one_line_exit_2(tmp_path, capsys):
    m = tmp_path / "jobs.csv"
    m.write_text("hdr-video,a.mp4,runs/a\nnot-a-command,b.mp4,runs/b\n")
    assert main(["batch", str(m)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "line 2" in err and "not-a-command" in err


def test_bad_options_fail_that_job_only(tmp_path, capsys):
    m = tmp_path / "jobs.csv"
    m.write_text("hdr-video,a.mp4,runs/a,--no-such-option\nhdr-video,b.mp4,runs/b,--out elsewhere\n")
    assert main(["batch", str(m), "--dry-run"]) == 1
    out = capsys.readouterr().out
    assert "no-such-option" in out and "output column" in out


def test_unclosed_quote_fails_that_line_only(tmp_path, capsys):
    """Issue 18 item 11: an unclosed quote is an error for its own line; it does not swallow the
    following lines into its options."""
    from layercam.commands.batch import read_manifest

    m = tmp_path / "jobs.csv"
    m.write_text('hdr-video,a.mp4,runs/a,"--preset fast\nhdr-video,b.mp4,runs/b,--preset fast '
                 '--ev-step 3\nhdr-video,c.mp4,runs/c,--set "x\n')
    jobs = read_manifest(m)
    assert [(j.line, j.output, j.status) for j in jobs] == [(1, "runs/a", "failed"),
                                                            (2, "runs/b", "pending"),
                                                            (3, "runs/c", "failed")]
    assert "unclosed quote" in jobs[0].reason and "closing quotation" in jobs[2].reason
    assert jobs[1].options == ["--preset", "fast", "--ev-step", "3"]
    assert main(["batch", str(m), "--dry-run"]) == 1
    assert "2 failed, 1 would run" in capsys.readouterr().out


def test_a_failed_job_decides_the_exit_status_even_when_the_summary_cannot_be_written(tmp_path, capsys):
    """Issue 18 item 11: the summary's own error (exit 2) must not hide "1 failed" (exit 1)."""
    from layercam.commands.batch import Job, report

    jobs = [Job(1, "hdr-video", "a.mp4", "runs/a", [], "failed", "exit 2: error: no such file")]
    blocker = tmp_path / "blocker"
    blocker.write_text("a file where the summary's folder should be")
    assert report(jobs, str(blocker / "summary.json")) == 1
    assert "cannot write the summary" in capsys.readouterr().err
    assert report([Job(1, "demo", "", "runs/d", [], "done")], str(blocker / "summary.json")) == 2
