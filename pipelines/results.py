"""What each stage leaves for the stages after it and for the report: ``Context.results[name]``.

One frozen class per stage. ``summary`` is what the stage returned from ``run`` and its
``done.json`` keeps (JSON: what the report shows); the other fields are what later stages read,
typed, loaded by the stage's ``load`` from the summary and its folder (arrays from disk). A stage
without a class of its own leaves a :class:`StageResult`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

PRIVATE = ("_seconds", "_cpu_seconds", "_outputs")  # what the runner adds to a summary (timing, outputs kept)


@dataclass(frozen=True)
class StageResult:
    summary: dict = field(default_factory=dict)

    def report(self) -> dict:
        """The summary as the report shows it (without the runner's private keys)."""
        return {k: v for k, v in self.summary.items() if k not in PRIVATE}


@dataclass(frozen=True)
class FlowResult(StageResult):
    """The flow stage's summary (``pairs``, ``working_size``, ``mean_flow_px``,
    ``consistent_fraction``); its arrays are ``Context.flow``
    (:class:`~layercam.vision.flow_store.FlowArrays`), opened once."""

    @property
    def pairs(self) -> int:
        return int(self.summary.get("pairs", 0))


@dataclass(frozen=True)
class BootstrapResult(StageResult):
    """``h0`` ``(L, T, 3, 3)``: each layer's initial mapping into its atlas; ``init_log2``: the
    atlas's initial log2 irradiance; ``static``: the camera did not move; ``masks`` ``(T, H, W)``
    motion masks (None unless the foreground finder made them); ``foreground``: how the foreground
    was found (``how``, ``masks``: "motion segmentation" | "given" | "none", the finder's
    ``verdict``), None for one layer."""

    h0: np.ndarray | None = None
    init_log2: Any = None
    static: bool = False
    masks: Any = None
    foreground: dict | None = None

    @property
    def verdict(self) -> dict:
        """The foreground finder's verdict (``found``, ``reason``;
        :mod:`layercam.vision.segment.verdict`), {} without one."""
        return dict((self.foreground or {}).get("verdict") or {})

    @property
    def motion_masks(self) -> bool:
        """The masks came from the motion segmentation (not given, not none)."""
        return (self.foreground or {}).get("masks") == "motion segmentation"


@dataclass(frozen=True)
class TrainResult(StageResult):
    """A training's summary: ``steps`` trained in all, ``resumed_from`` (the step a checkpoint
    held), ``final_loss`` (the last logged loss terms, None for a long clip's windows, whose
    summaries are ``windows``)."""

    @property
    def steps(self) -> int:
        return int(self.summary.get("steps", 0))

    @property
    def resumed_from(self):
        return self.summary.get("resumed_from")

    @property
    def final_loss(self) -> dict | None:
        return self.summary.get("final_loss")

    @property
    def windows(self) -> list[dict] | None:
        return self.summary.get("windows")


@dataclass(frozen=True)
class ExportResult(StageResult):
    """The export's summary and the arrays it kept for a scorer: ``frames`` (``deblurred.npy``,
    the sharp frames) and ``fused`` (``fused.npy``), None where the task writes none."""

    frames: Path | None = None
    fused: Path | None = None

    @property
    def atlas(self) -> dict | None:
        """The atlas export's summary (``foreground_share``: alpha's share of the frames), None without it."""
        return self.summary.get("atlas")


@dataclass(frozen=True)
class EvaluateResult(StageResult):
    """A scorer's result: ``metrics`` of layercam's output against the truth, ``baselines``
    (name -> metrics), and the scorer's other fields in ``summary``."""

    @property
    def metrics(self) -> dict | None:
        return self.summary.get("metrics")

    @property
    def baselines(self) -> dict:
        return self.summary.get("baselines") or {}
