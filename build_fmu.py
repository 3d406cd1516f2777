"""Export a scene as an FMI 2.0 Co-Simulation FMU: ``python build_fmu.py SCENE.toml -o OUT.fmu``.

The same as ``flexlink build`` (kept as the design card's script entry point)."""

import sys

from flexlink.cli import main

if __name__ == "__main__":
    sys.exit(main(["build", *sys.argv[1:]]))
