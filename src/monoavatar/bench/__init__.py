"""``monoavatar bench``: accuracy and speed of the reconstruction against the dissertation's
Table B.1, on a fixed, versioned suite of synthetic turn-around subjects.

- :mod:`monoavatar.bench.suite`: the subjects (seeds, garments, frames) and the two modes;
- :mod:`monoavatar.bench.metrics`: the truth, the result types and the surface error (through
  :mod:`monoavatar.eval`); :mod:`monoavatar.bench.heldout`: the held-out renders, the tracker's
  poses and the root error; :mod:`monoavatar.bench.evaluate`: one folder measured;
- :mod:`monoavatar.bench.ground_truth`: the surface error that ``demo`` and ``reconstruct``
  print for synth inputs;
- :mod:`monoavatar.bench.report`: ``results.json``, ``results.md`` and heat maps;
- :mod:`monoavatar.bench.runner`: :func:`run_bench`, the whole benchmark.
"""

from monoavatar.bench.metrics import HeatMap, SubjectMetrics, SurfaceMetrics
from monoavatar.bench.report import PUBLISHED, BenchResults, RunResult
from monoavatar.bench.runner import run_bench
from monoavatar.bench.suite import MODES, SUITE_VERSION, BenchMode, BenchSubject, get_suite

__all__ = [
    "MODES",
    "PUBLISHED",
    "SUITE_VERSION",
    "BenchMode",
    "BenchResults",
    "BenchSubject",
    "HeatMap",
    "RunResult",
    "SubjectMetrics",
    "SurfaceMetrics",
    "get_suite",
    "run_bench",
]
