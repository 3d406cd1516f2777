"""Output files named on the command line, checked before the work starts.

A command that simulates for minutes and then cannot write its ``--plot`` (a missing folder, a format
matplotlib does not know) has wasted the run and ends in a traceback. Every option that names a file to
write takes its value through :func:`output_file` or :func:`plot_file`; the value is then an
:class:`OutputPath`, and ``flexlink.cli.main`` calls :func:`check_output_paths` on the parsed arguments
before it runs the command, so that a bad path is one line and exit status 2, whatever the command.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
from pathlib import Path

from flexlink.errors import FlexlinkError

__all__ = ["FILM_WRITERS", "SCENE_HELP", "OutputPath", "check_output_paths", "film_file", "film_writer",
           "output_file", "plot_file", "stream_file"]


SCENE_HELP = "the scene file (TOML; docs/scene.md)"


class OutputPath(str):
    """A file the command will write (a ``str``, so that commands use it unchanged)."""

    plot = False
    film = False


class _PlotPath(OutputPath):
    plot = True


class _FilmPath(OutputPath):
    film = True


class _StreamPath(OutputPath):
    """A file, or ``-`` for standard output."""


#: a film's suffix → the matplotlib animation writer that makes it
FILM_WRITERS = {".gif": "pillow", ".mp4": "ffmpeg"}


def output_file(text: str) -> OutputPath:
    """The argparse ``type`` of an option naming a file the command writes.

    The value is marked as an :class:`OutputPath`, so that :func:`check_output_paths` finds it among the parsed
    arguments and checks its folder before the command runs.
    """
    return OutputPath(text)


def plot_file(text: str) -> OutputPath:
    """The argparse ``type`` of an option naming a figure.

    matplotlib picks the format from the suffix, so the path is marked as a plot: its suffix is checked against
    the formats matplotlib can write before the (possibly long) run, not after it.
    """
    return _PlotPath(text)


def stream_file(text: str) -> OutputPath:
    """The argparse ``type`` of an option naming a file the command writes, or ``-`` for standard output.

    ``-`` is exempt from the folder checks of :func:`check_output_path`; any other name is checked as a file.
    """
    return _StreamPath(text)


def film_file(text: str) -> OutputPath:
    """The argparse ``type`` of an option naming a film (.gif or .mp4).

    The film's writer is checked before the run (:func:`film_writer`: ffmpeg from PATH, else imageio-ffmpeg's
    bundled binary), so a film that cannot be written is refused in one line rather than after the simulation.
    """
    return _FilmPath(text)


def _plot_formats() -> set[str]:
    from matplotlib.backend_bases import FigureCanvasBase

    return set(FigureCanvasBase.get_supported_filetypes())


def check_output_path(path: OutputPath, option: str) -> None:
    """Refuse an output path that cannot be written where it points, before any work is done.

    Parameters
    ----------
    path : OutputPath
        The value of the option, as its argparse ``type`` marked it (plot, film, stream or plain file).
    option : str
        The option as the user typed it (``--plot``), named in the message.

    Raises
    ------
    FlexlinkError
        For an empty name, a folder, a parent folder that does not exist or is not writable, a figure format
        matplotlib does not know, a film whose writer is missing, or a name the operating system refuses.
    """
    if not path.strip():
        raise FlexlinkError(f"{option}: expected a file name, got an empty one")
    if path == "-" and isinstance(path, _StreamPath):
        return                      # standard output
    try:
        _check_place(path, option)
    except OSError as e:            # a name too long, a path through a file, …
        raise FlexlinkError(f"{option} {path}: cannot be written ({e.strerror})") from None


def _check_place(path: OutputPath, option: str) -> None:
    p = Path(path)
    if p.is_dir():
        raise FlexlinkError(f"{option} {path}: is a folder; expected a file name")
    if path.endswith(("/", os.sep)) or os.path.basename(path) in ("", ".", ".."):
        raise FlexlinkError(f"{option} {path}: names a folder (it ends in a separator, . or ..); expected a "
                            "file name")
    parent = p.parent
    if not parent.is_dir():
        raise FlexlinkError(f"{option} {path}: the folder {parent} does not exist; create it first")
    if not os.access(parent, os.W_OK):
        raise FlexlinkError(f"{option} {path}: the folder {parent} is not writable")
    _probe(parent, path, option)
    if path.plot:
        suffix = p.suffix.lower().lstrip(".")
        formats = _plot_formats()
        if suffix not in formats:
            raise FlexlinkError(f"{option} {path}: expected a figure file ending in one of "
                                f"{', '.join('.' + f for f in sorted(formats))}")
    if path.film:
        film_writer(p, option)


def _probe(parent: Path, path: str, option: str) -> None:
    """Make and remove a file in ``parent``, to know what its permission bits do not tell.

    Root writes everywhere by them, while /proc, /sys and a read-only mount refuse all the same.
    Only a file that cannot be made refuses the path; one that cannot be removed (a folder that only takes
    appends) is left, named ``.flexlink-probe-*``, since the real write will work.
    """
    try:
        fd, name = tempfile.mkstemp(prefix=".flexlink-probe-", dir=parent)
    except OSError as e:
        raise FlexlinkError(f"{option} {path}: the folder {parent} takes no new file ({e.strerror})") from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.remove(name)


def film_writer(path: str | os.PathLike, option: str = "-o") -> str:
    """The name of the matplotlib animation writer that makes the film ``path`` (by its suffix), made ready.

    An mp4 needs an ffmpeg binary. The one on PATH (or at matplotlib's ``animation.ffmpeg_path``) is used
    if there is one; otherwise the one shipped in the imageio-ffmpeg wheel, a dependency of flexlink, so
    that ``-o arm.mp4`` works after a plain ``pip install`` on a machine without ffmpeg: matplotlib's
    ``animation.ffmpeg_path`` is pointed at it for this process. Raises a :class:`FlexlinkError` naming
    ``option`` for a suffix that is not a film, or for an mp4 when no ffmpeg can be found at all.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in FILM_WRITERS:
        raise FlexlinkError(f"{option} {path}: expected a film ending in {' or '.join(FILM_WRITERS)}")
    name = FILM_WRITERS[suffix]
    from matplotlib import animation

    if not animation.writers.is_available(name) and name == "ffmpeg":
        _use_imageio_ffmpeg()
    if not animation.writers.is_available(name):
        raise FlexlinkError(f"{option} {path}: an mp4 needs ffmpeg, and there is none on PATH nor from the "
                            f"imageio-ffmpeg package; write a .gif (Pillow, always there) or install ffmpeg")
    return name


def _use_imageio_ffmpeg() -> None:
    """Point matplotlib's ffmpeg writer at imageio-ffmpeg's binary, if that package is there and has one."""
    try:
        import imageio_ffmpeg

        exe = imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):     # not installed; installed without a binary for this platform
        return
    import matplotlib

    matplotlib.rcParams["animation.ffmpeg_path"] = exe


def check_output_paths(args: argparse.Namespace, options: dict[str, str]) -> None:
    """Check every :class:`OutputPath` among the parsed arguments with :func:`check_output_path`.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line; a repeatable option's list is checked element by element.
    options : dict of str to str
        An argument's ``dest`` → the option as the user typed it (``--plot``), for the message; a ``dest``
        missing from it is named as is.

    Raises
    ------
    FlexlinkError
        For the first path that cannot be written.
    """
    for dest, value in vars(args).items():
        values = value if isinstance(value, list) else [value]
        for v in values:
            if isinstance(v, OutputPath):
                check_output_path(v, options.get(dest, dest))
