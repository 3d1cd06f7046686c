"""One run of neuralcol, end to end.

* :mod:`.context`: :class:`RunContext`, the pieces a run is built from (data set, features, latent space, labelers,
  label pool, oracle), each built once on first use; the diagnosis, the benchmarks and the studies use it too.
* :mod:`.steps`: the stages, each a function of what it needs returning a typed result.
* :mod:`.run`: :func:`run_pipeline`, the stages in order, the sittings' timings and ``metrics.json``.
* :mod:`.validate`: the run's settings checked before any work.
"""

from neuralcol.pipeline.context import LatentStage, RunContext
from neuralcol.pipeline.run import STAGES, Reporter, RunResults, run_pipeline

__all__ = ["STAGES", "LatentStage", "Reporter", "RunContext", "RunResults", "run_pipeline"]
