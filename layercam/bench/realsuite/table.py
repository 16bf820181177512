"""The real suite's table: ``real_suite.csv`` (every column) and ``real_suite.md`` (one table per
group of cases with the columns that group has, then what the analysis chose and why)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from layercam.core.config import DEFAULT_PRESET
from layercam.io.atomic import atomic_write

__all__ = ["CSV_FIELDS", "collect_rows", "write_table"]

CSV_FIELDS = [
    "case", "truth", "method", "preset", "psnr_mu", "psnr_mu_recov", "psnr_mu_fg", "clipped_pct",
    "psnr_t", "psnr_l_t", "ssim_t",
    "psnr_l", "ssim_mu", "channels", "flicker", "static_pct", "psnr", "ssim", "gain_db",
    "worst_gain_db", "frames_below", "psnr_aligned", "kept_share", "psnr_frames", "wall_s",
    "train_s", "steps", "peak_mem_mb", "load", "analysis", "code", "note", "failed",
]
PRESET_ORDER = {"": 0, "fast": 1, "balanced": 2, "quality": 3, "paper": 4}
_COLS = {  # group -> (title, [(header, field)])
    "bracket-gt": ("Brackets with ground truth (PSNR-mu against the ground truth's radiance, in "
                   "the medium shot's view)",
                   ["psnr_mu", "psnr_mu_recov", "clipped_pct", "psnr_t", "psnr_l_t", "ssim_t",
                    "channels"]),
    "bracket-ref": ("Brackets without ground truth (scored against a Robertson merge of all shots: "
                    "a reference, not truth)",
                    ["psnr_mu", "psnr_mu_recov", "clipped_pct", "psnr_t", "ssim_t"]),
    "composite": ("Composites of real material with ground truth (whole frame and the foreground's "
                  "own pixels)",
                  ["psnr_mu", "psnr_mu_fg", "psnr_mu_recov", "clipped_pct", "psnr_t", "ssim_t"]),
    "deblur": ("Real blurry video with sharp ground truth (PSNR / SSIM of the sharp frames, sRGB, "
               "whole frame; gain: over the blurry input, mean and worst frame)",
               ["psnr", "ssim", "gain_db", "worst_gain_db", "frames_below", "psnr_aligned",
                "kept_share"]),
    "video": ("Real video without ground truth (flicker: mean frame-to-frame change of the "
              "tonemapped output on static pixels, 8-bit codes)",
              ["flicker", "static_pct", "clipped_pct"]),
}
HOW = [
    "* PSNR-mu: `layercam.core.metrics` (one scale per channel, the median ratio; both divided by "
    "the truth's maximum; mu-law, mu = 5000). "
    "PSNR-T / PSNR-L / SSIM-T: the DeepHDRVideo protocol "
    "(`layercam.core.frame_metrics.deephdr_metrics`: one scale for all channels, truth divided by "
    "its maximum when above 1, per-frame means).",
    "* Scored channels: a channel of the truth that is 0 in over half its pixels is left out of "
    "every score (the NTIRE crops' green: a magenta-lit stage under the 16-bit source's floor).",
    "* Clipped everywhere: pixels that no exposure saw (some channel at or above 245/255, or every "
    "channel at or below 2/255, in every exposure): for the NTIRE crops and the composites, "
    "the truth rendered through the known camera at each exposure; for the other brackets the "
    "input shots themselves; for the Basler clip each pair of neighbouring frames. "
    "PSNR-mu recoverable: the same score on the other pixels.",
    "* Composites: PSNR-mu over all frames, and on the foreground's own pixels (coverage above 0.5 "
    "in the composite's masks), alignment from the whole frame.",
    "* Deblurring (GoPro clip): each method's sharp frames against the sharp ground truth, PSNR "
    "and SSIM (`layercam.core.metrics.ldr_metrics`) on the sRGB frames as written, "
    "whole frame, no shift; per frame in real_suite.csv (psnr_frames). The `input` row scores the "
    "blurry frames themselves: every method's floor. "
    "PSNR at the best shift: each frame first moved by the shift within 3 px that fits the truth "
    "best (an 8 px border left out), the sharpness apart from which instant of the exposure a "
    "frame shows. "
    "Share kept sharp: layercam's trust mask (`trust/`), the mean share of the sharp render in the "
    "written pixels, the input the rest.",
    "* Flicker (Basler clip): each method's HDR tonemapped with one global operator for the whole "
    "clip (as `preview.mp4`); frames t+1 warped into frame t's view "
    "(homographies from layercam's exposure-invariant DIS flow of the input); static pixels: where "
    "the input frames t and t+2 (same exposure), registered, differ by under 8/255 "
    "in every channel after a 3x3 blur, more than 4 px from any pixel that does not, seen by frame "
    "t or t+1; flicker = mean |D_t - D_(t+1)| there, in 8-bit codes.",
]
_HEAD = {
    "psnr_mu": "PSNR-mu", "psnr_mu_recov": "PSNR-mu recoverable",
    "psnr_mu_fg": "PSNR-mu foreground", "clipped_pct": "clipped everywhere %",
    "psnr_t": "PSNR-T", "psnr_l_t": "PSNR-L", "ssim_t": "SSIM-T", "flicker": "flicker",
    "static_pct": "static %", "channels": "scored channels",
    "psnr": "PSNR", "ssim": "SSIM", "gain_db": "gain dB", "worst_gain_db": "worst frame's gain dB",
    "frames_below": "frames below input", "psnr_aligned": "PSNR, each frame at its best shift",
    "kept_share": "share kept sharp",
}


def collect_rows(out: Path, cases: dict) -> list[dict]:
    """Every row of every finished job under ``out/cases``, with its case's columns, in case order
    (classical methods first, then the presets in dial order)."""
    order = {name: i for i, name in enumerate(cases)}
    rows = []
    for res_path in sorted(Path(out).glob("cases/*/*/result.json")):
        res = json.loads(res_path.read_text())
        name = res.get("job", {}).get("case")
        if name not in cases:
            continue
        prep_path = res_path.parents[1] / "prepare" / "result.json"
        prep = json.loads(prep_path.read_text()) if prep_path.exists() else {}
        for r in res.get("rows", []):
            row = {**r, "case": name, "truth": cases[name].truth, "code": res.get("code", "")}
            if "clipped_share" in prep:
                row["clipped_pct"] = round(100.0 * prep["clipped_share"], 2)
            if "static_share" in row:
                row["static_pct"] = round(100.0 * row.pop("static_share"), 1)
            rows.append(row)
    rows.sort(key=lambda r: (order[r["case"]], r["method"] == "layercam",
                             PRESET_ORDER.get(r.get("preset", ""), 9), r["method"]))
    return rows


_DIGITS = {"clipped_pct": 2, "static_pct": 1, "flicker": 2, "peak_mem_mb": 0, "psnr_mu": 2,
           "psnr_mu_recov": 2, "psnr_mu_fg": 2, "psnr_t": 2, "psnr_l_t": 2, "psnr_l": 2,
           "psnr": 2, "gain_db": 2, "worst_gain_db": 2, "psnr_aligned": 2, "kept_share": 2}


def _cell(v, field: str = "") -> str:
    if v is None or v == "":
        return ""
    if isinstance(v, dict):
        return v.get("choice", "")
    if isinstance(v, float):
        if field == "wall_s":
            return f"{v:.1f}" if v >= 10 else f"{v:.2f}"
        return f"{v:.{_DIGITS.get(field, 3)}f}"
    return str(v)


def _md_table(rows: list[dict], fields: list[str]) -> list[str]:
    head = ["case", "method", "preset", *[_HEAD[f] for f in fields], "wall s", "peak MB", "load"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        vals = [_cell(r.get(f), f) for f in fields]
        if r.get("failed"):
            vals = [f"failed: {r['failed']}"] + [""] * (len(fields) - 1)
        elif not any(r.get(f) is not None for f in _HEAD if f not in ("clipped_pct", "channels")):
            vals[0] = r.get("note", "")  # nothing scored: say why
        preset = f"`{r['preset']}`" if r.get("preset") else ""
        cells = [r["case"], r["method"], preset, *vals, _cell(r.get("wall_s"), "wall_s"),
                 _cell(r.get("peak_mem_mb"), "peak_mem_mb"), _cell(r.get("load"))]
        out.append("| " + " | ".join(cells) + " |")
    return out


def write_table(out: Path, rows: list[dict], cases: dict, command: str = "") -> None:
    """``out/real_suite.csv`` and ``out/real_suite.md`` (atomically)."""

    def w_csv(p: Path) -> None:
        with open(p, "w", newline="") as f:
            wr = csv.DictWriter(f, fieldnames=CSV_FIELDS)
            wr.writeheader()
            for r in rows:
                wr.writerow({k: (_cell(r.get(k), k) if k == "analysis" else " ".join(map(str, r[k]))
                                 if isinstance(r.get(k), list) else r.get(k, ""))
                             for k in CSV_FIELDS})

    atomic_write(Path(out) / "real_suite.csv", w_csv)
    codes = sorted({r.get("code", "") for r in rows if r.get("code")})
    md = ["# layercam real-capture suite", ""]
    if command:
        md += [f"Regenerate: `{command}`", ""]
    md += [f"Code: {', '.join(codes) or '?'}. Wall time is end to end for layercam (the command as "
           "typed: flow, analysis, training, export) and the merge alone for the classical "
           "methods; `load` is the 1-minute load average at the job's start and end (timings "
           "under load are not final).", ""]
    for group, (title, fields) in _COLS.items():
        g = [r for r in rows if cases[r["case"]].group == group]
        if g:
            md += [f"## {title}", "", *_md_table(g, fields), ""]
    md += _targets(rows, cases)
    chosen = [r for r in rows if r["method"] == "layercam" and isinstance(r.get("analysis"), dict)]
    if chosen:
        md += ["## What the analysis chose, and why (report.json[\"analysis\"])", "",
               "| case | preset | choice | reasons |", "|---|---|---|---|"]
        for r in chosen:
            why = "; ".join(f"{k}: {v}" for k, v in r["analysis"].get("reasons", {}).items())
            md.append(f"| {r['case']} | `{r['preset']}` | {r['analysis']['choice']} | {why} |")
        md.append("")
    md += ["## Cases", "",
           *[f"* `{c.name}` ({c.truth}): {c.about}" for c in cases.values()
             if any(r["case"] == c.name for r in rows)], ""]
    md += ["## How it is measured", "", *HOW, ""]
    atomic_write(Path(out) / "real_suite.md", lambda p: p.write_text("\n".join(md)))


def _targets(rows: list[dict], cases: dict) -> list[str]:
    """Issue 14's targets, case by case: on brackets with ground truth layercam's PSNR-mu above
    Debevec's; on the composites the whole frame above flow + Debevec and the foreground at least
    1 dB above it; on the Basler clip flicker no higher than flow + Debevec's; and the dial
    (fast <= balanced <= quality within 0.2 dB) where more than one preset ran. Issue 43's on the
    deblurring case: every preset above the blurry input, the default (balanced) by 2 dB, no
    frame below its input."""
    out = []
    ok = [r for r in rows if not r.get("failed")]
    for name, case in cases.items():
        mine = [r for r in ok if r["case"] == name and r["method"] == "layercam"]
        base = {r["method"]: r for r in ok if r["case"] == name and r["method"] != "layercam"}
        for r in mine:
            if case.group == "bracket-gt" and "debevec" in base and r.get("psnr_mu") is not None:
                d = r["psnr_mu"] - base["debevec"]["psnr_mu"]
                out.append((name, r["preset"], "PSNR-mu above OpenCV Debevec",
                            f"{r['psnr_mu']:.2f} vs {base['debevec']['psnr_mu']:.2f} ({d:+.2f} dB)",
                            d > 0))
            if case.group == "composite" and "flow+debevec" in base and r.get("psnr_mu") is not None:
                b = base["flow+debevec"]
                d, dfg = r["psnr_mu"] - b["psnr_mu"], r["psnr_mu_fg"] - b["psnr_mu_fg"]
                out.append((name, r["preset"], "whole frame above flow + Debevec",
                            f"{r['psnr_mu']:.2f} vs {b['psnr_mu']:.2f} ({d:+.2f} dB)", d > 0))
                out.append((name, r["preset"], "foreground >= 1 dB above flow + Debevec",
                            f"{r['psnr_mu_fg']:.2f} vs {b['psnr_mu_fg']:.2f} ({dfg:+.2f} dB)",
                            dfg >= 1.0))
            if case.group == "video" and "flow+debevec" in base and r.get("flicker") is not None:
                b = base["flow+debevec"]["flicker"]
                out.append((name, r["preset"], "flicker no higher than flow + Debevec",
                            f"{r['flicker']:.2f} vs {b:.2f}", r["flicker"] <= b))
            if case.group == "deblur" and r.get("gain_db") is not None:
                out.append((name, r["preset"],
                            "above the blurry input"
                            + (" by 2 dB (the default)" if r["preset"] == DEFAULT_PRESET else ""),
                            f"{r['psnr']:.2f} dB ({r['gain_db']:+.2f} dB)",
                            r["gain_db"] >= (2.0 if r["preset"] == DEFAULT_PRESET else 0.0)
                            and r["gain_db"] > 0))
                out.append((name, r["preset"], "no frame below its input",
                            f"worst frame {r['worst_gain_db']:+.2f} dB, {r['frames_below']} below",
                            r["frames_below"] == 0))
        key = "psnr" if case.group == "deblur" else "psnr_mu"
        dial = sorted((r for r in mine if r.get(key) is not None and r["preset"] in PRESET_ORDER),
                      key=lambda r: PRESET_ORDER[r["preset"]])
        for a, b in zip(dial, dial[1:]):
            out.append((name, f"{a['preset']} -> {b['preset']}", "dial monotone (within 0.2 dB)",
                        f"{a[key]:.2f} -> {b[key]:.2f}", b[key] >= a[key] - 0.2))
    if not out:
        return []
    md = ["## Targets (issues 14 and 43)", "", "| case | preset | target | measured | met |", "|---|---|---|---|---|"]
    md += [f"| {c} | `{p}` | {t} | {m} | {'yes' if y else '**no**'} |" for c, p, t, m, y in out]
    return md + [""]
