"""What the model contains for one clip: chosen by ``layercam.analyse`` or forced by flags."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field


@dataclass
class ModelSpec:
    layers: int = 1                 # 1 (static or rigid scene) or 2 (an object moves on its own)
    tone_mapper: str = "learned"    # "learned" CRF, or "fixed" sRGB for a single exposure
    exposures: str = "given"        # "given" or "learned"
    blur: str = "off"               # "off", "3x3" or "5x5"
    max_offset: float = 5.0         # blur generator's maximum offset, pixels
    flow_loss: bool = True
    reasons: dict = field(default_factory=dict)

    @property
    def blur_n(self) -> int:
        return {"off": 0, "3x3": 3, "5x5": 5}[self.blur]

    def to_dict(self) -> dict:
        return asdict(self)

    def key_dict(self) -> dict:
        """What a cache key depends on (the reasons do not change the model)."""
        d = asdict(self)
        d.pop("reasons")
        return d
