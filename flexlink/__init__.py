"""flexlink: flexible-link robots from a TOML scene to an FMI 2.0 or 3.0 FMU (Co-Simulation and Model Exchange).

The package is a pipeline, one stage per sub-package (docs/pipeline.md): ``scene`` → ``mechanics`` → ``export``
→ ``run``, with ``tools`` beside it.  Docstrings cite the two founding texts as *seed 000* and *seed 001*
(docs/validation.md, "Sources").
"""

__version__ = "0.1.0"
