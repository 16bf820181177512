"""Progress bars: tqdm on a terminal, silent when output is not a terminal (logs, CI) or ``--quiet``."""

from __future__ import annotations


def bar(iterable=None, total=None, desc: str = "", unit: str = "it", enabled: bool = True, initial: int = 0):
    from tqdm.auto import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, initial=initial, leave=False,
                dynamic_ncols=True, disable=None if enabled else True)
