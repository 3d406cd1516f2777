"""argparse types and choices that the controllers' sub-commands share (``flexlink control``, ``linearize``, ``sweep``).

They live apart from the commands so that each command module imports them without importing another
command: ``controllers.cli`` registers ``flexlink sweep``, and the sweep's ``--target`` reads angles as
``flexlink control``'s does.
"""

from __future__ import annotations

import argparse

from flexlink.options import finite

__all__ = ["SENSORS", "add_weight_options", "angles", "finite", "limits", "positive"]

#: The Kalman sensors besides the joint encoders (``--sensors`` of ``flexlink control`` and ``sweep``).
SENSORS = ("strain", "accelerometer")


def angles(text: str) -> list[float]:
    """``--target``: one angle in degrees, or one per torque-driven joint separated by commas."""
    return [finite(v) for v in text.split(",")]


def positive(text: str) -> float:
    """A finite number above zero: a limit of the LQR's weights or of a torque."""
    v = finite(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def limits(text: str) -> list[float] | dict[str, float]:
    """A limit per joint, link or mode: ``V`` (every one), ``V,V,…`` (one each, in scene order) or ``NAME=V,…``.

    Every value must be positive (a Bryson limit is the deviation that costs as much as the others' limits;
    zero or less has no meaning).  Names are checked against the scene by :mod:`controllers.weights`, which
    knows it; here only the syntax, so that a typo costs no model build.
    """
    items = [s.strip() for s in text.split(",")]
    if not all(items):
        raise argparse.ArgumentTypeError(f"expected V, V,V,... or NAME=V,..., got {text!r}")
    named = ["=" in s for s in items]
    if any(named) and not all(named):
        raise argparse.ArgumentTypeError(f"give every value a name or none, got {text!r}")
    if not any(named):
        return [positive(s) for s in items]
    out: dict[str, float] = {}
    for s in items:
        name, _, value = s.partition("=")
        name = name.strip()
        if not name or name in out:
            what = f"a repeated name {name!r}" if name else "an empty name"
            raise argparse.ArgumentTypeError(f"{what} in {text!r}")
        out[name] = positive(value.strip())
    return out


def add_weight_options(p: argparse.ArgumentParser, torque_help: str) -> None:
    """The LQR's limits, registered alike on ``flexlink control`` and ``flexlink sweep``.

    ``--torque-limit`` (its help, ``torque_help``, says the command's default), ``--joint-error``,
    ``--tip-deflection``, ``--root-moment`` and ``--mode-limit``: one value for all, one per item in scene order,
    or by name (:func:`limits`; names checked by :mod:`controllers.weights`).
    """
    p.add_argument("--torque-limit", type=limits, metavar="NM[,NM...]|JOINT=NM,...", help=torque_help)
    p.add_argument("--joint-error", type=limits, metavar="DEG[,DEG...]|JOINT=DEG,...",
                   help="Bryson limit of each joint's angle error in the LQR weights: one for all, one per joint "
                        "with an encoder in scene order, or by joint name (default 0.5 deg; smaller = heavier)")
    p.add_argument("--tip-deflection", type=limits, metavar="MM[,MM...]|LINK=MM,...",
                   help="Bryson limit of each link's tip deflection (tip.v) in mm: one for all, one per flexible "
                        "link in scene order, or by link name (default 5 mm)")
    p.add_argument("--root-moment", type=limits, metavar="NM[,NM...]|LINK=NM,...",
                   help="Bryson limit of each link's root bending moment in the LQR weights: one for all, one per "
                        "link, or by link name (default: 10 %% of the torque limit of the joint carrying the link; "
                        "the torque limit itself gives the two-link example >= 6 dB and >= 30 deg at each "
                        "actuator, docs/control.md)")
    p.add_argument("--mode-limit", type=limits, metavar="V|LINK=V,...|LINK.eta[K]=V,...",
                   help="Bryson limit of modal coordinates (the FMU outputs <link>.eta[k]): one for every mode, all "
                        "the modes of a link by its name, or one mode by its output name (default: none, the "
                        "modes weighed through the tip deflection and root moment)")
