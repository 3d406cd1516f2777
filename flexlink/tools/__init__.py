"""Tools beside the pipeline: they use its stages, and no stage uses them.

Input: a scene file or an FMU (ours or anyone's).  Output: reports, not FMUs: ``check`` (compliance harness)
with ``importers`` (independent FMI importers), ``bench`` (speed against error), ``explain`` and
``fidelity`` (what a model contains, the fidelity ladder), ``demo`` (the quick start's open-loop job) and
``reference`` (the scene and command references of docs/, generated from the code).  Parameter sweeps need
a closed loop and live in the ``controllers`` application (``flexlink sweep``).
"""
