"""Stage 2 — mechanics: a :class:`~flexlink.scene.loader.Scene` in, a symbolic model out.

Input: a validated scene.  Output: a :class:`~flexlink.mechanics.model.SymbolicModel` (CasADi
Functions of the residual r(q, v, a, u, p) and the outputs, with the parameter, input, output and
coordinate tables).  On the way: shape functions and their constant integrals (``shapes/``), the
positions of the sections to first or second order (``kinematics``), energies → Lagrange
(``model``).  Beside the stage, on the same symbolic model: equilibrium, linearisation and
frequencies (``analysis``) and the CVODES reference simulation (``reference``).
"""
