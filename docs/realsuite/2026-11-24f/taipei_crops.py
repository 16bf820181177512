"""The dial and export.denoise at the sample floor on a real static camera: twelve 256x256 crops of
bracket_taipei (3 shots each: 4 / 1 / 1/4 s and 2 / 1/2 / 1/8 s), each fused by layercam with
fast, balanced and quality and scored (PSNR-mu, the real suite's score) against the crop of the
Robertson merge of all ten shots (a reference, not truth), next to OpenCV Debevec on the same
shots. Run from the repository root: python docs/realsuite/2026-11-24f/taipei_crops.py OUT
[--set export.denoise=off]; about 12 minutes on 2 cores."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from layercam.io import load_clip, read_exr
from layercam.bench.realsuite.cases import read_image_list
from layercam.bench.realsuite.classical import bracket_merges, robertson_reference
from layercam.bench.realsuite.measures import score_hdr, unseen_mask

data = Path("../shared/data/bracket_taipei")
out = Path(sys.argv[1])
extra = sys.argv[2:]
table = read_image_list(data / "image_list.txt")
names = sorted(table)
ref = robertson_reference(load_clip([data / n for n in names]).frames, np.array([table[n] for n in names]))
subsets = {"a": ["DSC_0061.png", "DSC_0063.png", "DSC_0065.png"], "b": ["DSC_0062.png", "DSC_0064.png", "DSC_0066.png"]}
rows = []
for sname, shots in subsets.items():
    for y in (0, 254):
        for x in (0, 256, 512):
            case = out / f"tp{sname}_{y}_{x}"
            case.mkdir(parents=True, exist_ok=True)
            paths = []
            for i, n in enumerate(shots):
                cv2.imwrite(str(case / f"{i}.png"), cv2.imread(str(data / n), cv2.IMREAD_UNCHANGED)[y:y + 256, x:x + 256])
                paths.append(str(case / f"{i}.png"))
            (case / "times.txt").write_text("".join(f"{table[n]}\n" for n in shots))
            frames = load_clip(paths).frames
            crop, unseen = ref[y:y + 256, x:x + 256], unseen_mask(frames)
            row = [case.name]
            for preset in ("fast", "balanced", "quality"):
                run = case / preset
                subprocess.run(["layercam", "fuse-stack", *paths, "--exposures", str(case / "times.txt"), "--reference", "1", "--preset", preset, "--out", str(run), "--quiet", *extra], check=True)
                row.append(score_hdr(read_exr(run / "fused.exr"), crop, unseen, None)["psnr_mu"])
            times = np.array([table[n] for n in shots])
            row.append(score_hdr(bracket_merges(frames, times)["debevec"]["hdr"], crop, unseen, None)["psnr_mu"])
            rows.append(row)
            print(" ".join([row[0]] + [f"{v:.2f}" for v in row[1:]]), flush=True)
print("mean", " ".join(f"{v:.2f}" for v in np.mean([r[1:] for r in rows], 0)))
