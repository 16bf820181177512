"""The cases of the real-capture suite: what layercam is given (the command line a user would type),
what the classical methods are given (the same images, loaded as layercam loads them) and what the
result is scored against.

Groups:

* ``bracket-gt``: ``hdr_ntire_crops/00000N``, three LDR exposures (-3/-1/+1 EV) with real motion,
  scored against the crop's ground-truth radiance (:func:`ntire_truth`) in the view of the medium
  shot (``--reference 1``).
* ``bracket-ref``: ``bracket_taipei`` (3 of its 10 shots) and ``bracket_frobisher_exif`` (its 3
  shots), scored against a Robertson merge of ALL the bracket's shots: a reference, not truth
  (for frobisher the reference is made of the very shots that are scored).
* ``composite``: :mod:`layercam.bench.realsuite.composite` clips (2 and 3 EV steps; one with the camera
  held still, where the export merges neighbours), ground truth per frame, scored on the whole frame
  and on the foreground's own pixels.
* ``video``: the Basler clip, no ground truth: figure and flicker on static background.
* ``deblur``: ``deblur_gopro0477_dev``, 12 blurry frames made from real 240 fps GoPro footage,
  run through ``deblur-video`` at half size (640x360) and scored (PSNR, SSIM, sRGB) against the
  sharp frames (the middle 240 fps frame of each blurry frame's window), next to the blurry input
  itself (the floor) and the classical deblurring a user could run. ``gopro-shake``: one of its
  sharp frames, still, shaken along known hand-held paths (:class:`ShakeSpec`): the camera shake
  alone, where the method's assumptions hold, scored the same way against the sharp frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.bench.realsuite.composite import CompositeSpec, ShakeSpec, read_image_list

__all__ = ["Case", "CASES", "case_inputs", "load_inputs", "load_truth", "read_prediction"]

TAIPEI_SUBSET = ("DSC_0061.png", "DSC_0063.png", "DSC_0065.png")  # 4 s, 1 s, 1/4 s: two stops apart around the middle
NTIRE_GAMMA = 2.24  # the NTIRE 2021 challenge's LDR formation (hdr_ntire_crops/SOURCE.txt)


@dataclass
class Case:
    """One case: ``name``, its ``group`` (see the module docstring), what it is scored against
    (``truth``: "truth", "reference, not truth" or "none"), the layercam command (``task``) and a
    one-line ``about`` for the table; ``params`` are the group's own settings."""

    name: str
    group: str
    truth: str
    task: str
    about: str
    params: dict = field(default_factory=dict)


def _cases() -> list[Case]:
    out = [
        Case(f"ntire-{i:06d}", "bracket-gt", "truth", "fuse-stack",
             f"hdr_ntire_crops/{i:06d}: 3 shots -3/-1/+1 EV, real motion, 256x256",
             {"folder": f"hdr_ntire_crops/{i:06d}"})
        for i in range(4)
    ]
    out += [
        Case("taipei-3", "bracket-ref", "reference, not truth", "fuse-stack",
             "bracket_taipei: shots 4 s, 1 s, 1/4 s of 10, 768x510; reference: Robertson merge of "
             "all 10", {"folder": "bracket_taipei", "shots": TAIPEI_SUBSET}),
        Case("frobisher", "bracket-ref", "reference, not truth", "fuse-stack",
             "bracket_frobisher_exif: 3 JPEGs 1/8, 1, 8 s (EXIF), 640x426; reference: Robertson "
             "merge of the same 3 shots", {"folder": "bracket_frobisher_exif"}),
        Case("composite-2ev", "composite", "truth", "hdr-video",
             "parkour person over a taipei radiance map, pan, filmic curve, noise, 8 bit; 24 "
             "frames 384x256 alternating 2 EV", {"ev_step": 2.0}),
        Case("composite-3ev", "composite", "truth", "hdr-video",
             "as composite-2ev, alternating 3 EV", {"ev_step": 3.0}),
        Case("composite-still", "composite", "truth", "hdr-video",
             "as composite-2ev, the camera held still: the export merges neighbours, as for the "
             "Basler clip", {"ev_step": 2.0, "still": True}),
        Case("basler", "video", "none", "hdr-video",
             "altexp_video_basler/clip_2exp_3stop.mp4: real alternating 3 EV video, 256x136, "
             "person walking", {"video": "altexp_video_basler/clip_2exp_3stop.mp4"}),
        Case("gopro-0477", "deblur", "truth", "deblur-video",
             "deblur_gopro0477_dev: 12 blurry frames (15 frames of real 240 fps GoPro footage "
             "averaged), hand-held, a dribbling player; --resize 0.5 (640x360)",
             {"folder": "deblur_gopro0477_dev", "resize": "0.5"}),
        Case("gopro-shake", "deblur", "truth", "deblur-video",
             "a still: deblur_gopro0477_dev's sharp frame 6 at 640x360, shaken along known "
             "hand-held paths (blur 0.2-8 px, linear light, 8 bit); 12 frames 448x256",
             {"shake": True}),
    ]
    return out


CASES = {c.name: c for c in _cases()}


def composite_spec(case: Case, quick: bool) -> CompositeSpec:
    kw = {"ev_step": case.params["ev_step"], "still": bool(case.params.get("still", False))}
    return CompositeSpec(frames=6, size=(48, 64), **kw) if quick else CompositeSpec(**kw)


def shake_spec(quick: bool) -> ShakeSpec:
    return ShakeSpec(frames=3, size=(48, 64), max_blur_px=3.0) if quick else ShakeSpec()


def _need(path: Path) -> Path:
    if not path.exists():
        raise LayercamError(f"missing shared capture {path} (see ../shared/data/README.md)")
    return path


def case_inputs(case: Case, case_dir: Path, data: Path, quick: bool = False, max_frames: int | None = None) -> dict:
    """What layercam is run on: ``{"paths": [...], "argv": CLI arguments after the command (inputs
    and input options, no --out/--preset), "load": load_clip keyword arguments}``. Writes what the
    command reads (an exposure-times file, the composite's frames) into ``case_dir/inputs``."""
    inp = Path(case_dir) / "inputs"
    inp.mkdir(parents=True, exist_ok=True)
    if case.group == "bracket-gt":
        folder = _need(data / case.params["folder"])
        evs = np.load(folder / "exposures.npy").astype(float)
        times = inp / "times.txt"
        times.write_text("".join(f"{2.0 ** e:g}\n" for e in evs))
        paths = [folder / f"{i}.png" for i in range(3)]
        return {"paths": paths, "argv": [*map(str, paths), "--exposures", str(times), "--reference", "1"], "load": {}}
    if case.name == "taipei-3":
        folder = _need(data / case.params["folder"])
        paths = [folder / n for n in case.params["shots"]]
        return {"paths": paths,
                "argv": [*map(str, paths), "--exposures", str(folder / "image_list.txt"),
                         "--reference", "1"], "load": {}}
    if case.name == "frobisher":
        paths = sorted(_need(data / case.params["folder"]).glob("IMG_*.jpg"))
        return {"paths": paths, "argv": [*map(str, paths), "--exposures", "exif", "--reference", "1"], "load": {}}
    if case.group == "composite":
        frames_dir = inp / "frames"
        return {"paths": frames_dir,
                "argv": [str(frames_dir), "--exposures", "alt", "--ev-step",
                         f"{case.params['ev_step']:g}"], "load": {}}
    if case.group == "video":
        video = _need(data / case.params["video"])
        n = 6 if quick else max_frames
        extra = ["--max-frames", str(n)] if n else []
        return {"paths": video,
                "argv": [str(video), "--exposures", "alt", "--ev-step", "3", *extra],
                "load": {"max_frames": n}}
    if case.group == "deblur" and case.params.get("shake"):
        frames_dir = inp / "frames"
        return {"paths": frames_dir, "argv": [str(frames_dir)], "load": {}}
    if case.group == "deblur":
        blur = _need(data / case.params["folder"] / "blur")
        n = 3 if quick else max_frames
        resize = "0.125" if quick else case.params["resize"]
        extra = ["--max-frames", str(n)] if n else []
        return {"paths": blur, "argv": [str(blur), "--resize", resize, *extra],
                "load": {"max_frames": n, "resize": resize}}
    raise LayercamError(f"unknown case group {case.group!r}")


def load_inputs(case: Case, ci: dict) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    """The frames exactly as layercam loads them ``(T,H,W,3)`` in [0,1], their exposure times in
    seconds (relative for the composites and the Basler clip, whose times are known only as a
    ratio) and their names."""
    from layercam.io import load_clip, parse_exposures

    clip = load_clip(ci["paths"] if isinstance(ci["paths"], list) else ci["paths"], **ci["load"])
    if case.group == "bracket-gt":
        times = np.array([float(v) for v in Path(ci["argv"][ci["argv"].index("--exposures") + 1]).read_text().split()])
    elif case.name == "taipei-3":
        table = read_image_list(Path(ci["argv"][ci["argv"].index("--exposures") + 1]))
        times = np.array([table[Path(p).name] for p in ci["paths"]])
    elif case.name == "frobisher":
        times = np.array(clip.exif_exposures, dtype=np.float64)
    elif case.group == "deblur":  # one exposure
        times = np.ones(clip.T)
    else:  # alternating: what the user tells layercam (alt, --ev-step), phases measured from the frames
        ex = parse_exposures("alt", clip, float(ci["argv"][ci["argv"].index("--ev-step") + 1]))
        times = np.exp2(ex.log2_dt.astype(np.float64))
    return clip.frames, times, list(clip.names)


def load_truth(case: Case, case_dir: Path, data: Path, frames: np.ndarray, times: np.ndarray) -> dict | None:
    """``{"hdr": (H,W,3) or (T,H,W,3), "unseen": bool mask without channels, "fg": (T,H,W) bool
    (composites)}``, ``{"sharp": (T,H,W,3)}`` in [0,1] for a deblurring case (the sharp frames loaded
    as its inputs are), or None for a case without ground truth. Cached in ``case_dir/truth.npz``."""
    from layercam.bench.realsuite.measures import unseen_mask

    cache = Path(case_dir) / "truth.npz"
    if cache.exists():
        z = np.load(cache)
        return {k: z[k] for k in z.files}
    if case.group == "video":
        return None
    if case.group == "deblur" and case.params.get("shake"):
        out = {"sharp": np.load(Path(case_dir) / "inputs" / "shake.npz")["sharp"]}
        if out["sharp"].shape != frames.shape:
            raise LayercamError(f"{case.name}: the sharp frames {out['sharp'].shape} do not match "
                                f"the shaken ones {frames.shape}")
        np.savez(cache, **out)
        return out
    if case.group == "deblur":
        from layercam.io import load_clip

        t, h, w = frames.shape[:3]  # the sharp frames at the size and count the blurry ones were loaded
        sharp = load_clip(_need(data / case.params["folder"] / "sharp"), max_frames=t, resize=f"{w}x{h}").frames
        if sharp.shape != frames.shape:
            raise LayercamError(f"{case.name}: the sharp frames {sharp.shape} do not match the "
                                f"blurry ones {frames.shape}")
        out = {"sharp": sharp}
        np.savez(cache, **out)
        return out
    if case.group == "bracket-gt":
        gt = ntire_truth(data / case.params["folder"])
        rel = times / times[1]  # the medium shot is the reference view
        renders = np.clip(gt[None] * rel[:, None, None, None], 0, 1) ** (1.0 / NTIRE_GAMMA)
        out = {"hdr": gt, "unseen": unseen_mask(renders)}
    elif case.group == "bracket-ref":
        from layercam.bench.realsuite.classical import robertson_reference

        if case.name == "taipei-3":
            from layercam.io import load_clip

            folder = data / case.params["folder"]
            table = read_image_list(folder / "image_list.txt")
            names = sorted(table)
            ref = robertson_reference(load_clip([folder / n for n in names]).frames,
                                      np.array([table[n] for n in names]))
        else:
            ref = robertson_reference(frames, times)
        out = {"hdr": ref, "unseen": unseen_mask(frames)}
    elif case.group == "composite":
        z = np.load(Path(case_dir) / "inputs" / "composite.npz")
        from layercam.bench.realsuite.composite import expose

        spec = CompositeSpec(**{k: (tuple(v) if k == "size" else v) for k, v in _spec_dict(z).items()})
        ts = np.unique(z["times"])
        renders = np.stack([expose(z["hdr"], np.full(len(z["hdr"]), t), None, spec)
                            for t in ts]).astype(np.float32) / 255.0
        out = {"hdr": z["hdr"], "unseen": unseen_mask(renders), "fg": z["alpha"] > 0.5}
    else:
        raise LayercamError(f"unknown case group {case.group!r}")
    np.savez(cache, **out)
    return out


def ntire_truth(folder: Path) -> np.ndarray:
    """An NTIRE crop's linear radiance ``(H,W,3)`` RGB, on the medium shot's scale: decoded from the
    16-bit source as SOURCE.txt says, ``(gt.png / alignratio) ** 2.24``. ``gt_linear.hdr`` holds
    the same radiance re-encoded as Radiance RGBE, whose shared 8-bit mantissa rounds a channel far
    below its pixel's brightest to 0, a ceiling that would hide differences between methods
    (docs/measurements.md). It is used only where ``gt.png`` is missing."""
    import cv2

    if (folder / "gt.png").exists() and (folder / "alignratio.npy").exists():
        g16 = cv2.imread(str(folder / "gt.png"), cv2.IMREAD_UNCHANGED)[..., ::-1].astype(np.float64)
        return ((g16 / float(np.load(folder / "alignratio.npy"))) ** NTIRE_GAMMA).astype(np.float32)
    return cv2.imread(str(_need(folder / "gt_linear.hdr")), cv2.IMREAD_UNCHANGED)[..., ::-1].astype(np.float32)


def _spec_dict(z) -> dict:
    import json

    return json.loads(str(z["spec"]))


def prepare_composite(case: Case, case_dir: Path, data: Path, shared_dir: Path, quick: bool) -> None:
    """Render the composite's frames into ``case_dir/inputs/frames`` and its ground truth into
    ``inputs/composite.npz`` unless they are there for the same spec. The background radiance map
    is cached in ``shared_dir`` for every composite."""
    from layercam.bench.realsuite.composite import compose, load_background, load_foreground

    spec = composite_spec(case, quick)
    npz, key = _rendered(case_dir, "composite.npz", spec)
    if npz is None:
        return
    shared_dir.mkdir(parents=True, exist_ok=True)
    bg_path = shared_dir / "taipei_radiance.npy"
    if not bg_path.exists():
        np.save(bg_path, load_background(data))
    rgb, alpha = load_foreground(data, spec.fg_clip, spec.frames)
    res = compose(np.load(bg_path), rgb, alpha, spec)
    _write_frames(case_dir, res["frames"])
    np.savez(npz, hdr=res["hdr"], alpha=res["alpha"], times=res["times"], spec=key)


def _rendered(case_dir: Path, name: str, spec) -> tuple[Path | None, str]:
    """``(inputs/name, spec's key)``, or ``(None, key)`` when that file holds this spec's render already."""
    import json

    npz = Path(case_dir) / "inputs" / name
    key = json.dumps(spec.key(), sort_keys=True)
    return (None if npz.exists() and str(np.load(npz)["spec"]) == key else npz), key


def _write_frames(case_dir: Path, frames: np.ndarray) -> None:
    """A rendered clip's uint8 RGB frames as ``inputs/frames/frame_NNN.png`` (replacing any there);
    the case's cached truth goes with them."""
    import cv2

    frames_dir = Path(case_dir) / "inputs" / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    for old in frames_dir.glob("*.png"):
        old.unlink()
    for t, f in enumerate(frames):
        cv2.imwrite(str(frames_dir / f"frame_{t:03d}.png"), np.ascontiguousarray(f[..., ::-1]))
    (Path(case_dir) / "truth.npz").unlink(missing_ok=True)


def prepare_shake(case: Case, case_dir: Path, data: Path, quick: bool) -> None:
    """Render ``gopro-shake``'s frames into ``case_dir/inputs/frames`` and its sharp frames into
    ``inputs/shake.npz`` unless they are there for the same spec."""
    from layercam.bench.realsuite.composite import load_still, shake_still

    spec = shake_spec(quick)
    npz, key = _rendered(case_dir, "shake.npz", spec)
    if npz is None:
        return
    _need(Path(data) / spec.source)
    res = shake_still(load_still(data, spec), spec)
    _write_frames(case_dir, res["frames"])
    np.savez(npz, sharp=res["sharp"], blur_length=res["blur_length"], spec=key)


def read_prediction(case: Case, run_dir: Path, n: int) -> np.ndarray:
    """layercam's linear HDR: ``fused.exr`` ``(H,W,3)`` for a stack, ``hdr/frame_*.exr``
    ``(T,H,W,3)`` for a video; for deblurring its sharp frames ``frames/frame_*.png`` ``(T,H,W,3)``
    in [0,1]."""
    from layercam.io import read_exr

    if case.task == "deblur-video":
        from layercam.io import load_clip

        return load_clip([Path(run_dir) / "frames" / f"frame_{t:05d}.png" for t in range(n)]).frames
    if case.task == "fuse-stack":
        return read_exr(Path(run_dir) / "fused.exr")
    return np.stack([read_exr(Path(run_dir) / "hdr" / f"frame_{t:05d}.exr") for t in range(n)])
