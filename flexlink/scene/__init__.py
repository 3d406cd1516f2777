"""Stage 1 — the scene: a TOML file in, a validated, typed :class:`Scene` out.

Input: a scene file (``*.toml``). Output: plain frozen data classes (:class:`Scene`, :class:`Joint`,
:class:`Link`, ...) in SI units, every mistake reported as one :class:`~flexlink.errors.SceneError`
naming the file and the key.  Nothing here knows about CasADi, C or FMI.

``schema.py``: the data classes and :data:`~flexlink.scene.schema.KEYS`, the table of every scene key (the
scene reference); ``loader.py``: TOML → objects, reading the keys the table lists; ``checks.py``: the
checks that relate several keys, and the form of every error.
"""
