"""Shared settings and helpers of the property-based (hypothesis) tests of numerical stability at the
extremes: exposure ratios from 2^-12 to 2^12, log irradiances up to the guard (+-40 stops) and beyond,
half-precision inputs and autocast, parameters scaled far from their initialisation.

Examples are derandomised so that the suite is reproducible; ``LAYERCAM_EXPLORE=1`` searches ten
times as many fresh random examples.
"""

from __future__ import annotations

import os

import numpy as np
import torch
from hypothesis import HealthCheck, settings, strategies as st
from hypothesis.extra import numpy as hnp

from layercam.core.config import SceneConfig


_EXPLORE = bool(os.environ.get("LAYERCAM_EXPLORE"))


def props(n: int):
    """Settings for a property: ``n`` examples (x10 when exploring), no deadline, no database."""
    return settings(
        max_examples=n * (10 if _EXPLORE else 1), deadline=None, derandomize=not _EXPLORE, database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


DTYPES = st.sampled_from([torch.float32, torch.float16, torch.bfloat16])


AUTOCAST = st.sampled_from([None, torch.bfloat16, torch.float16])


EV = st.floats(-12.0, 12.0)  # log2 exposure: ratios 2^-12 .. 2^12


SIZES = st.sampled_from([(1, 1), (2, 3), (3, 2), (5, 7), (7, 5)])


SCENE = SceneConfig(grid_levels=2, atlas_width=8, deform_width=8)
SIZES_SMALL = {"grid_max_res": 8, "alpha_grid_res": 8}  # the derived sizes
                                                        # (layercam.scene.layered.derived_sizes) of
                                                        # a tiny scene


Z = torch.linspace(-20.0, 20.0, 2001)  # stops, for monotonicity


def _autocast(dtype):
    return torch.autocast("cpu", dtype=dtype) if dtype is not None else torch.autocast("cpu", enabled=False)


def _finite(*ts) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in ts)


def _grads_finite(module: torch.nn.Module) -> bool:
    return all(p.grad is None
               or bool(torch.isfinite(p.grad._values() if p.grad.is_sparse else p.grad).all())
               for p in module.parameters())


def _scale_params(module: torch.nn.Module, scale: float) -> None:
    with torch.no_grad():
        for p in module.parameters():
            p.mul_(scale)


def _z_values(n=64, big=1e4):
    """log2 exposures z: the whole guarded range and beyond, with exact extremes."""
    edge = st.sampled_from([0.0, -big, big, -40.0, 40.0, -20.0, 20.0, 65504.0, -65504.0])
    return hnp.arrays(np.float32, (n, 3), elements=st.one_of(edge, st.floats(-big, big, width=32)))
