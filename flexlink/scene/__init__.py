"""Stage 1 — the scene: a TOML file in, a validated, typed :class:`Scene` out.

Input: a scene file (``*.toml``). Output: plain frozen data classes (:class:`Scene`, :class:`Joint`,
:class:`Link`, ...) in SI units, every mistake reported as one :class:`~flexlink.errors.SceneError`
naming the file and the key.  Nothing here knows about CasADi, C or FMI.
"""
