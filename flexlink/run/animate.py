"""The moving arm as a film: its deformed centre line at every communication point of an FMU run.

The joint angles and elastic coordinates come from the FMU's outputs; the shape between root and tip is the
model's own (:mod:`flexlink.mechanics.centreline`). Deflections of a real arm are millimetres on metres, so
they are magnified: every drawn point is ``P₀ + K (P − P₀)``, where P is the deformed point and P₀ the same
point with every elastic coordinate η set to zero (the rigid arm at the same joint angles). Joint angles,
the elastic joints' link-side angles and the rigid motion stay true to scale; only η's effect is multiplied.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from flexlink.errors import FlexlinkError
from flexlink.mechanics.centreline import Centreline
from flexlink.paths import film_writer

VIEWS = ("auto", "3d", "xy", "xz", "yz")
MAX_FRAMES = 3000           # a film of more frames is minutes of drawing: ask for a lower --fps instead
VISIBLE = 0.08              # default magnification: the largest drawn deflection is about this share of the reach


@dataclass
class ArmFilm:
    """What is drawn at each frame, from an FMU run.

    ``drawn`` (frames × points × 3, magnified) and ``rigid`` (the same points with η = 0) at the ``times``;
    the magnification and the largest true deflection are kept to be written in every frame.
    """

    line: Centreline
    times: np.ndarray
    drawn: np.ndarray
    rigid: np.ndarray
    magnification: float
    deflection: float           # largest |P − P₀| over the run and the arm, m (true size)

    @property
    def tip(self) -> np.ndarray:
        """The drawn end of the arm (the tool point, or the last tip) at every frame."""
        return self.drawn[:, self.line.polyline[-1]]


def nice_floor(x: float) -> float:
    """The largest 1, 2 or 5 × 10ⁿ not above x (a magnification a reader takes in at a glance)."""
    exponent = math.floor(math.log10(x))
    for m in (5, 2, 1):
        if m * 10**exponent <= x:
            return float(m * 10**exponent)
    return float(10**exponent)


def arm_film(line: Centreline, result, magnify: float | None = None, frame_step: float | None = None) -> ArmFilm:
    """The film of an fmpy result that holds every coordinate of ``line`` (the FMU outputs of those names).

    With ``frame_step``, only the result's samples on that grid are frames (fmpy adds one at each input
    jump, between frames). ``magnify`` None: the 1, 2 or 5 × 10ⁿ that makes the largest deflection about
    ``VISIBLE`` of the arm's reach (at least 1).
    """
    times = np.asarray(result["time"], float)
    keep = np.append(np.diff(times) > 0, True)       # a time sampled twice (an input jump): the later sample
    if frame_step is not None:
        keep &= np.abs(times / frame_step - np.round(times / frame_step)) < 1e-6
    result, times = result[keep], times[keep]
    qa = np.column_stack([result[name] for name in line.coordinates])
    deformed = np.stack([line.points(q) for q in qa])
    rigid = np.stack([line.points(np.where(line.elastic, 0.0, q)) for q in qa])
    deflection = float(np.max(np.linalg.norm(deformed - rigid, axis=2)))
    if magnify is None:
        reach = float(np.max(np.linalg.norm(rigid - rigid[:, :1], axis=2)))
        magnify = nice_floor(VISIBLE * reach / deflection) if deflection > 0 and reach > 0 else 1.0
        magnify = max(magnify, 1.0)
    if not (math.isfinite(magnify) and magnify > 0):
        raise FlexlinkError(f"--magnify must be a positive number, got {magnify}")
    drawn = rigid + magnify * (deformed - rigid)
    return ArmFilm(line, times, drawn, rigid, float(magnify), deflection)


def _projection(points: np.ndarray, view: str) -> str:
    """``auto``: the plane the whole film lies in (a planar arm), else ``3d``."""
    if view != "auto":
        return view
    span = np.ptp(points.reshape(-1, 3), axis=0)
    flat = span <= 1e-9 * max(float(np.max(span)), 1e-300)
    if flat[2]:
        return "xy"
    if flat[1]:
        return "xz"
    if flat[0]:
        return "yz"
    return "3d"


def _limits(points: np.ndarray) -> tuple[np.ndarray, float]:
    lo, hi = points.reshape(-1, 3).min(axis=0), points.reshape(-1, 3).max(axis=0)
    centre, half = (lo + hi) / 2, 0.55 * max(float(np.max(hi - lo)), 1e-6)
    return centre, half


class FilmFigure:
    """A matplotlib figure of the film, and ``draw(k)``, which puts frame k in it.

    One figure serves the animation writer, the still frame, and the tests that read back what was drawn.
    """

    def __init__(self, film: ArmFilm, title: str = "", view: str = "auto"):
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        self.film = film
        both = np.concatenate([film.drawn, film.rigid], axis=1)
        self.view = _projection(both, view)
        self.axes_index = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2), "3d": (0, 1, 2)}[self.view]
        self.fig = plt.figure(figsize=(6.4, 5.4))
        centre, half = _limits(both)
        if self.view == "3d":
            ax = self.fig.add_subplot(projection="3d")
            for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
                set_lim(c - half, c + half)
            ax.set_box_aspect((1, 1, 1))
            ax.view_init(elev=22, azim=-55)
            ax.set_zlabel("z (m)")
        else:
            ax = self.fig.add_subplot()
            i, j = self.axes_index
            ax.set_xlim(centre[i] - half, centre[i] + half)
            ax.set_ylim(centre[j] - half, centre[j] + half)
            ax.set_aspect("equal")
            ax.grid(alpha=0.3)
        names = "xyz"
        ax.set_xlabel(f"{names[self.axes_index[0]]} (m)")
        ax.set_ylabel(f"{names[self.axes_index[1]]} (m)")
        self.ax = ax
        self.ghost = self._plot([], [], color="0.6", lw=1.0, ls="--", label="rigid arm (η = 0)")
        self.arm = self._plot([], [], color="C0", lw=2.5, label="deformed arm")
        self.joints = self._plot([], [], ls="", marker="o", ms=7, mfc="white", mec="k", label="joints")
        self.payloads = self._plot([], [], ls="", marker="s", ms=10, color="C3",
                                   label="payload" if film.line.payloads else None)
        self.tip = self._plot([], [], ls="", marker="^", ms=7, color="k", label="tip / tool")
        ax.legend(loc="upper right", fontsize=7)
        ax.set_title(title)
        self.fig.tight_layout(rect=(0, 0.05, 1, 0.95))
        self.clock = self.fig.text(0.02, 0.965, "", fontsize=10, family="monospace")
        self.fig.text(0.02, 0.015, f"deflection × {film.magnification:g} (largest true deflection "
                      f"{film.deflection * 1e3:.3g} mm); joint angles true to scale", fontsize=8)

    def _plot(self, x, y, **style):
        if self.view == "3d":
            return self.ax.plot(x, y, [], **style)[0]
        return self.ax.plot(x, y, **style)[0]

    def _set(self, artist, points: np.ndarray) -> None:
        if self.view == "3d":
            artist.set_data_3d(points[:, 0], points[:, 1], points[:, 2])
        else:
            i, j = self.axes_index
            artist.set_data(points[:, i], points[:, j])

    def draw(self, k: int) -> list:
        """Put frame k in the figure; the artists it changed (what ``FuncAnimation`` redraws)."""
        f, line = self.film, self.film.line
        self._set(self.ghost, f.rigid[k, line.polyline])
        self._set(self.arm, f.drawn[k, line.polyline])
        self._set(self.joints, f.drawn[k, line.joints])
        self._set(self.payloads, f.drawn[k, line.payloads].reshape(-1, 3))
        self._set(self.tip, f.drawn[k, line.polyline[-1:]])
        self.clock.set_text(f"t = {f.times[k]:7.3f} s")
        return [self.ghost, self.arm, self.joints, self.payloads, self.tip, self.clock]

    def close(self) -> None:
        """Free the figure (pyplot keeps every open figure alive)."""
        import matplotlib.pyplot as plt

        plt.close(self.fig)


def write_film(film: ArmFilm, path: str | os.PathLike, *, fps: float, title: str = "", view: str = "auto",
               still: str | os.PathLike | None = None) -> FilmFigure:
    """Write the film (gif: Pillow; mp4: ffmpeg) and, if asked, a still PNG of the frame of the largest deflection.

    Returns the figure (closed), whose ``view`` says which projection was drawn. The writer comes from
    :func:`flexlink.paths.film_writer`, which finds an ffmpeg for an mp4 or says why there is none.
    """
    from matplotlib import animation

    figure = FilmFigure(film, title, view)
    try:
        # matplotlib's stubs say int; both writers take a rate in frames per second as a float (--fps 12.5)
        writer = animation.writers[film_writer(path)](fps=fps)  # type: ignore[arg-type]
        movie = animation.FuncAnimation(figure.fig, figure.draw, frames=len(film.times), blit=False)
        movie.save(str(path), writer=writer, dpi=90)
        if still is not None:
            k = int(np.argmax(np.max(np.linalg.norm(film.drawn - film.rigid, axis=2), axis=1)))
            figure.draw(k)
            figure.fig.savefig(still, dpi=110)
    finally:
        figure.close()
    return figure
