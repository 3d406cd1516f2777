"""Stage 4 — run: an FMU in, trajectories and linear plants out.

Input: an FMU file (and a scene or symbolic model where a linearisation needs one).  Output:
simulation results (``simulate``: runs through fmpy), python-control state-space plants with named
signals (``linearize``) and films of the deformed arm (``animate``).  Every Python caller hosts the FMU
through ``host`` (:class:`~flexlink.run.host.FmuHost`); ``progress`` reports a long run as it goes.
"""

#: How ``--input`` is applied between its rows (``flexlink simulate``, ``animate``): here, not in
#: :mod:`.simulate`, so that building the command line's parser imports neither numpy nor fmpy.
INTERPOLATIONS = ("linear", "hold")
