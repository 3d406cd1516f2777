"""Tools beside the pipeline: they use its stages, and no stage uses them.

``check`` (compliance harness) with ``importers`` (independent FMI importers), ``bench`` (speed
against error), ``explain`` and ``fidelity`` (what a model contains, the fidelity ladder), ``sweep``
(parameter studies on Dask) and ``demo`` (the quick start's open-loop job).
"""
