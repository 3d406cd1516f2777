"""Stage 4 — run: an FMU in, trajectories and linear plants out.

Input: an FMU file (and a scene or symbolic model where a linearisation needs one).  Output:
simulation results (``simulate``: runs through fmpy) and python-control state-space plants with named
signals (``linearize``).
"""
