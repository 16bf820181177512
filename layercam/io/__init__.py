"""Input/output: clips (video, image folders), exposure specs, PNG/EXR/mp4 writers.

Heavy libraries (OpenCV, imageio-ffmpeg, OpenEXR, Pillow) are imported inside the functions
that need them, so importing this package costs only numpy.
"""

from layercam.io.atomic import atomic_write, ensure_writable_dir
from layercam.io.clip import Clip
from layercam.io.decode import load_clip, probe_clip
from layercam.io.exposure import Exposures, parse_exposures
from layercam.io.exr import read_exr, write_exr
from layercam.io.images import IMAGE_SUFFIXES, read_exif_exposure, read_image, write_png
from layercam.io.video import VIDEO_SUFFIXES, VideoWriter, read_video, write_video

__all__ = [
    "Clip",
    "load_clip",
    "probe_clip",
    "Exposures",
    "parse_exposures",
    "read_image",
    "write_png",
    "read_exif_exposure",
    "read_video",
    "write_video",
    "VideoWriter",
    "read_exr",
    "write_exr",
    "atomic_write",
    "ensure_writable_dir",
    "IMAGE_SUFFIXES",
    "VIDEO_SUFFIXES",
]
