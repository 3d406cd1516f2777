"""Stage 3 — export: a symbolic model in, an FMU file out.

Input: a :class:`~flexlink.mechanics.model.SymbolicModel`.  Output: ``OUT.fmu`` (modelDescription.xml,
``binaries/linux64``, ``sources/``).  On the way: the FMU variable table (``variables``), forward
derivatives and the model structure (``derivatives``), CasADi → C and the generated model half
(``codegen``), one compiler call (``cbuild``), the model descriptions (``description`` for FMI 2.0 and the
pieces both versions share, ``fmi3``) and the build and packaging (``fmu``).
The generic C half lives in ``fmu_src/`` and knows nothing about beams.
"""
