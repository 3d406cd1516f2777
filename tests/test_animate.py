"""``flexlink animate``: what each frame draws is the FMU's arm.

The drawn end of the arm is compared with the FMU's own ``tip.x/y/z`` outputs (computed in the FMU's C, not
by the drawing); the magnification is checked against the rigid geometry of the rotating link, L (cos θ,
sin θ) from the FMU's hub angle: the joint stays where it is, and only the tip's departure from the rigid
arm is multiplied. On the command line: a GIF with one frame per communication point, and a bad ``-o`` is
refused before anything is built.

An mp4 is decoded back by ffmpeg (imageio-ffmpeg's reader, not matplotlib): its frame count, size and rate
are the film's, and each decoded frame is the figure matplotlib renders for that frame to within the h264
codec's error, measured as PSNR (peak signal-to-noise ratio over all pixels and channels, 8 bits).
"""

from __future__ import annotations

import io
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from conftest import EXAMPLES

from flexlink.errors import FlexlinkError
from flexlink.mechanics.centreline import centreline
from flexlink.paths import film_writer
from flexlink.run.animate import FilmFigure, arm_film, write_film
from flexlink.run.simulate import simulate
from flexlink.scene.loader import load_scene

ROOT = Path(__file__).resolve().parents[1]
TIP = ["tip.x", "tip.y", "tip.z"]


def drawn_arm(film, k: int) -> np.ndarray:
    """The arm's polyline as the figure holds it after drawing frame k (3 columns; z = 0 in a planar view)."""
    figure = FilmFigure(film)
    try:
        figure.draw(k)
        if figure.view == "3d":
            return np.column_stack(figure.arm.get_data_3d())
        x, y = figure.arm.get_data()
        assert figure.view == "xy"
        return np.column_stack([x, y, np.zeros_like(x)])
    finally:
        figure.close()


@pytest.fixture(scope="module")
def rotating(example_fmu):
    """The rotating link under a 0.5 N m torque reversed at 0.3 s: its FMU run with every coordinate."""
    line = centreline(load_scene(EXAMPLES / "rotating_link.toml"))
    torque = np.array([(0.0, 0.5), (0.3, 0.5), (0.3, -0.5), (1.0, -0.5)], dtype=[("time", float), ("hub.tau", float)])
    result = simulate(example_fmu("rotating_link"), 0.6, step=0.02, inputs=torque,
                      outputs=[*line.coordinates, *TIP])
    return line, result


def test_drawn_tip_is_the_fmu_tip(rotating):
    line, result = rotating
    film = arm_film(line, result, magnify=1.0)
    for k in (5, len(result) - 1):
        arm = drawn_arm(film, k)
        assert arm[-1] == pytest.approx([result[c][k] for c in TIP], abs=1e-9)
        assert np.max(np.abs(arm[:, 2])) == 0.0


def test_magnification_multiplies_the_deflection_only(rotating):
    """Drawn tip = L (cos θ, sin θ) + K (FMU tip − L (cos θ, sin θ)); the hub joint stays at the origin."""
    line, result = rotating
    length, magnify = 2.2, 7.0
    film = arm_film(line, result, magnify=magnify)
    k = len(result) - 1
    theta = result["hub.theta"][k]
    rigid = length * np.array([np.cos(theta), np.sin(theta)])
    fmu_tip = np.array([result["tip.x"][k], result["tip.y"][k]])
    assert np.linalg.norm(fmu_tip - rigid) > 1e-3                      # the arm is bent: the test can fail
    arm = drawn_arm(film, k)
    assert arm[-1, :2] == pytest.approx(rigid + magnify * (fmu_tip - rigid), abs=1e-9)
    assert arm[0] == pytest.approx([0.0, 0.0, 0.0], abs=1e-15)
    assert film.magnification == magnify
    theta_run = result["hub.theta"]
    tip_departure = np.hypot(result["tip.x"] - length * np.cos(theta_run), result["tip.y"] - length * np.sin(theta_run))
    # the largest true deflection of the run and the arm: at least the tip's, and (bending, not a wave) near it
    assert np.max(tip_departure) - 1e-12 <= film.deflection <= 1.2 * np.max(tip_departure)


def test_spatial_arm_drawn_tip_is_the_fmu_tool_point(example_fmu):
    """The six-axis arm (3-D view, a tool frame and a payload): the drawn end is the FMU's tool position."""
    line = centreline(load_scene(EXAMPLES / "six_axis_arm.toml"))
    result = simulate(example_fmu("six_axis_arm"), 0.4, step=0.1, outputs=[*line.coordinates, *TIP])
    film = arm_film(line, result, magnify=1.0)
    arm = drawn_arm(film, len(result) - 1)
    assert arm[-1] == pytest.approx([result[c][-1] for c in TIP], abs=1e-9)
    assert line.payloads and len(line.joints) == 6


def decoded_mp4(path: Path) -> tuple[dict, list[np.ndarray]]:
    """ffmpeg's reading of an mp4: its metadata (size, fps, codec) and every frame as height × width × RGB."""
    import imageio_ffmpeg

    frames = imageio_ffmpeg.read_frames(str(path))
    meta = next(frames)
    width, height = meta["size"]
    return meta, [np.frombuffer(f, np.uint8).reshape(height, width, 3) for f in frames]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio of two 8-bit images, dB (∞ when equal)."""
    mse = float(np.mean((a.astype(float) - b.astype(float)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(255**2 / mse)


def rendered(figure: FilmFigure, k: int, dpi: float) -> np.ndarray:
    """Frame k as matplotlib renders it for an animation writer (RGBA at the film's dpi), as RGB."""
    figure.draw(k)
    buffer = io.BytesIO()
    figure.fig.savefig(buffer, format="rgba", dpi=dpi)
    width, height = (figure.fig.get_size_inches() * dpi).round().astype(int)
    return np.frombuffer(buffer.getvalue(), np.uint8).reshape(height, width, 4)[..., :3]


def test_mp4_decodes_to_the_frames_drawn(rotating, tmp_path):
    """31 frames at 25 fps, 576 × 486 (6.4 × 5.4 in at 90 dpi); each decoded frame within h264's error of
    matplotlib's frame (PSNR > 38 dB; measured 43–44 dB) and clearly not another frame (< 35 dB; measured 26–31)."""
    line, result = rotating
    film = arm_film(line, result, magnify=7.0)
    write_film(film, tmp_path / "arm.mp4", fps=25)
    meta, frames = decoded_mp4(tmp_path / "arm.mp4")
    assert len(frames) == len(film.times) == round(0.6 / 0.02) + 1
    assert meta["codec"] == "h264" and meta["fps"] == 25.0
    assert meta["size"] == (576, 486)
    figure = FilmFigure(film)
    try:
        for k in (0, 12, len(frames) - 1):
            assert psnr(frames[k], rendered(figure, k, 90)) > 38
            assert psnr(frames[k], rendered(figure, (k + 15) % len(frames), 90)) < 35   # the metric can tell
    finally:
        figure.close()


@pytest.fixture
def no_ffmpeg_on_path(monkeypatch, tmp_path):
    """PATH holds no ffmpeg and matplotlib looks for plain ``ffmpeg`` (restored after the test)."""
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.setitem(matplotlib.rcParams, "animation.ffmpeg_path", "ffmpeg")
    monkeypatch.delenv("IMAGEIO_FFMPEG_EXE", raising=False)


def test_mp4_takes_ffmpeg_from_imageio_ffmpeg_when_none_on_path(no_ffmpeg_on_path):
    import imageio_ffmpeg

    assert film_writer("arm.mp4") == "ffmpeg"
    assert matplotlib.rcParams["animation.ffmpeg_path"] == imageio_ffmpeg.get_ffmpeg_exe()


def test_mp4_prefers_the_ffmpeg_on_path(monkeypatch, tmp_path):
    """An ffmpeg on PATH (here a stand-in script) is the user's choice: matplotlib keeps looking it up."""
    monkeypatch.setitem(matplotlib.rcParams, "animation.ffmpeg_path", "ffmpeg")
    stand_in = tmp_path / "ffmpeg"
    stand_in.write_text("#!/bin/sh\nexit 0\n")
    stand_in.chmod(0o755)
    monkeypatch.setenv("PATH", str(tmp_path))
    assert film_writer("arm.mp4") == "ffmpeg"
    assert matplotlib.rcParams["animation.ffmpeg_path"] == "ffmpeg"


def _no_binary():
    raise RuntimeError("No ffmpeg exe could be found.")


@pytest.mark.parametrize("imageio_ffmpeg", [None, "no binary"])
def test_mp4_without_any_ffmpeg_is_one_clear_error(no_ffmpeg_on_path, monkeypatch, imageio_ffmpeg):
    """imageio-ffmpeg not installed (the import fails), or installed without a binary for this platform."""
    if imageio_ffmpeg is None:
        monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    else:
        import imageio_ffmpeg as module

        monkeypatch.setattr(module, "get_ffmpeg_exe", _no_binary)
    with pytest.raises(FlexlinkError, match="an mp4 needs ffmpeg.*write a .gif"):
        film_writer("arm.mp4")
    assert film_writer("arm.gif") == "pillow"


def flexlink(*args: str, cache: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "XDG_CACHE_HOME": str(cache), "MPLBACKEND": "Agg", **(env or {})}
    return subprocess.run([sys.executable, "-m", "flexlink.cli", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300, check=False)


def test_cli_writes_a_gif_and_a_still(tmp_path, example_fmu):
    from PIL import Image

    example_fmu("rotating_link")                        # the shared cache holds the FMU
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    (tmp_path / "in.csv").write_text("time,hub.tau\n0,0.5\n0.13,0.5\n0.13,-0.5\n1,-0.5\n")   # a jump between frames
    done = flexlink("animate", "examples/rotating_link.toml", "--stop-time", "0.4", "--input", str(tmp_path / "in.csv"),
                    "-o", str(tmp_path / "arm.gif"), "--still", str(tmp_path / "arm.png"), cache=cache)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    with Image.open(tmp_path / "arm.gif") as gif:
        assert gif.n_frames == round(0.4 * 25) + 1         # one frame per 1/25 s (fmpy's sample at the jump is not)
    assert (tmp_path / "arm.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "deflection ×" in done.stdout


def test_cli_writes_an_mp4_without_ffmpeg_on_path(tmp_path, example_fmu):
    """The project's own install suffices: PATH without ffmpeg, the wheel's binary writes the film."""
    example_fmu("rotating_link")
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    done = flexlink("animate", "examples/rotating_link.toml", "--stop-time", "0.4", "--fps", "20",
                    "-o", str(tmp_path / "arm.mp4"), cache=cache, env={"PATH": _path_without_ffmpeg()})
    assert done.returncode == 0, done.stderr
    meta, frames = decoded_mp4(tmp_path / "arm.mp4")
    assert len(frames) == round(0.4 * 20) + 1 and meta["fps"] == 20.0 and meta["size"] == (576, 486)


def _path_without_ffmpeg() -> str:
    return os.pathsep.join(d for d in os.environ.get("PATH", "").split(os.pathsep)
                           if d and not shutil.which("ffmpeg", path=d))


@pytest.mark.parametrize("name, words", [("missing/arm.gif", ["does not exist"]), ("arm.avi", [".gif", ".mp4"]),
                                         ("arm.mp4", ["ffmpeg"])])
def test_bad_output_is_refused_before_the_run(tmp_path, name, words):
    """One line, exit 2, in an empty cache that stays empty: nothing was built or run. The mp4: no ffmpeg on
    PATH, and imageio-ffmpeg told (by its documented variable) to use a binary that is not there."""
    cache = tmp_path / "cache"
    cache.mkdir()
    t0 = time.perf_counter()
    no_ffmpeg = {"PATH": _path_without_ffmpeg(), "IMAGEIO_FFMPEG_EXE": str(tmp_path / "no-such-ffmpeg")}
    done = flexlink("animate", "examples/rotating_link.toml", "--stop-time", "1", "-o", str(tmp_path / name),
                    cache=cache, env=no_ffmpeg if name.endswith(".mp4") else None)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert all(w in done.stderr for w in words), done.stderr
    assert not any(cache.rglob("*.fmu")) and time.perf_counter() - t0 < 30
