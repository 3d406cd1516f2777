"""argparse types the commands share: numbers refused at the command line, where the message can name the option.

A value such as ``--rate nan`` that reached the model would fail far from its cause (a static equilibrium
that does not converge); argparse names the option and exits with status 2.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["finite"]


def finite(text: str) -> float:
    """A finite number: argparse reports anything else as a usage error naming the option."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v
