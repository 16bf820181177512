"""layercam: invert the imaging process with layered neural atlases and an implicit camera model."""

__version__ = "0.1.0"
