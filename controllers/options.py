"""argparse types and choices that the controllers' sub-commands share (``flexlink control``, ``linearize``, ``sweep``).

They live apart from the commands so that each command module imports them without importing another
command: ``controllers.cli`` registers ``flexlink sweep``, and the sweep's ``--target`` reads angles as
``flexlink control``'s does.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["SENSORS", "angles", "finite"]

#: The Kalman sensors besides the joint encoders (``--sensors`` of ``flexlink control`` and ``sweep``).
SENSORS = ("strain", "accelerometer")


def finite(text: str) -> float:
    """A finite number: argparse reports anything else as a usage error naming the option."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def angles(text: str) -> list[float]:
    """``--target``: one angle in degrees, or one per torque-driven joint separated by commas."""
    return [finite(v) for v in text.split(",")]
