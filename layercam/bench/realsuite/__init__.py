"""The real-capture benchmark suite (``layercam bench --suite real``): layercam, run as a user would,
next to the classical merges a user would otherwise run, on the real captures in ``../shared/data``
and on composites of real material with ground truth.

* :mod:`~layercam.bench.realsuite.cases`: the cases, their command lines, inputs and truth or reference;
* :mod:`~layercam.bench.realsuite.composite`: the composites (real radiance map, real DAVIS foreground,
  a filmic camera, noise, 8 bits, alternating exposures);
* :mod:`~layercam.bench.realsuite.classical`: OpenCV Debevec, Robertson, Mertens, flow + Debevec;
* :mod:`~layercam.bench.realsuite.measures`: clipped-everywhere pixels, static pixels, flicker, scores;
* :mod:`~layercam.bench.realsuite.jobs`: one job in its own process; :mod:`~layercam.bench.realsuite.suite`:
  the resumable run; :mod:`~layercam.bench.realsuite.table`, :mod:`~layercam.bench.realsuite.figures`: outputs.
"""

from layercam.bench.realsuite.cases import CASES
from layercam.bench.realsuite.suite import run_real_suite

__all__ = ["CASES", "run_real_suite"]
