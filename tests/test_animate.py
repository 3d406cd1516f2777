"""``flexlink animate``: what each frame draws is the FMU's arm.

The drawn end of the arm is compared with the FMU's own ``tip.x/y/z`` outputs (computed in the FMU's C, not
by the drawing); the magnification is checked against the rigid geometry of the rotating link, L (cos θ,
sin θ) from the FMU's hub angle: the joint stays where it is, and only the tip's departure from the rigid
arm is multiplied. On the command line: a GIF with one frame per communication point, and a bad ``-o`` is
refused before anything is built.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES

from flexlink.mechanics.centreline import centreline
from flexlink.run.animate import FilmFigure, arm_film
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


def flexlink(*args: str, cache: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "XDG_CACHE_HOME": str(cache), "MPLBACKEND": "Agg"}
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


@pytest.mark.parametrize("name, words", [("missing/arm.gif", ["does not exist"]), ("arm.avi", [".gif", ".mp4"]),
                                         ("arm.mp4", ["ffmpeg"])])
def test_bad_output_is_refused_before_the_run(tmp_path, name, words):
    """One line, exit 2, in an empty cache that stays empty: nothing was built or run."""
    if name.endswith(".mp4") and shutil.which("ffmpeg"):
        pytest.skip("ffmpeg is installed: an mp4 can be written")
    cache = tmp_path / "cache"
    cache.mkdir()
    t0 = time.perf_counter()
    done = flexlink("animate", "examples/rotating_link.toml", "--stop-time", "1", "-o", str(tmp_path / name),
                    cache=cache)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert all(w in done.stderr for w in words), done.stderr
    assert not any(cache.rglob("*.fmu")) and time.perf_counter() - t0 < 30
