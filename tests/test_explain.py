"""``flexlink explain`` and "only what the scene needs": terms appear exactly when the scene asks for them."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import parse_scene
from flexlink.tools.explain import STEPS_PER_PERIOD, explain

BASE = tomllib.loads(Path("examples/rotating_link.toml").read_text())


def _scene(**changes):
    data = json.loads(json.dumps(BASE))
    for key, value in changes.items():
        section, _, name = key.partition("__")
        if section == "fmu":
            data.setdefault("fmu", {})[name] = value
        elif section in ("link", "joint"):
            data[section][0][name] = value
        else:
            data[key] = value
    return parse_scene(data)


@pytest.mark.parametrize(("changes", "present", "absent"), [
    ({}, [], ["gravity[1]", "arm.kelvin_voigt", "arm.payload.mass", "hub.damping"]),
    ({"gravity": [0, -9.81, 0]}, ["gravity[2]"], ["arm.kelvin_voigt"]),
    ({"fmu__tunable": ["gravity", "arm.kelvin_voigt", "hub.damping"]}, ["gravity[1]", "arm.kelvin_voigt",
                                                                        "hub.damping"], ["arm.payload.mass"]),
    ({"link__kelvin_voigt": 1e-3, "joint__damping": 0.01}, ["arm.kelvin_voigt", "hub.damping"], ["gravity[1]"]),
    ({"link__payload": {"mass": 0.5}}, ["arm.payload.mass"], ["gravity[1]"]),
])
def test_only_the_terms_the_scene_needs(changes, present, absent):
    names = [p.name for p in build_model(_scene(**changes)).parameters]
    assert all(n in names for n in present), names
    assert not any(n in names for n in absent), names


def test_recommended_step_resolves_the_highest_mode():
    info = explain("examples/rotating_link.toml")
    f = natural_frequencies(build_model(_scene())).frequencies_hz
    assert info["frequencies_hz"] == pytest.approx(f)
    assert info["recommended_step"] == pytest.approx(1 / (STEPS_PER_PERIOD * max(f)))
    assert info["coordinates"] == ["hub.theta", "arm.eta[1]", "arm.eta[2]", "arm.eta[3]"]


def test_cli_explain_prints_coordinates_terms_and_step():
    out = subprocess.run([sys.executable, "-m", "flexlink.cli", "explain", "examples/steel_beam_raise.toml"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for words in ("coordinates", "gravity", "second-order", "recommended SS22 step", "prescribed"):
        assert words in out.stdout


def test_explain_lists_the_robot_bodies_coordinates_and_terms():
    """Issue 15: the six-axis arm's explanation names every joint and the body it drives (from the scene:
    the column's 8 kg, the wrist's massless connectors, the shoulder's placement), its 13 coordinates
    (6 + 6 elastic ones of the two tubes, the elastic elbow's link angle) and a term per link."""
    from flexlink.tools.explain import format_explanation

    info = explain("examples/six_axis_arm.toml")
    bodies = info["bodies"]
    assert [b.split('"')[1] for b in bodies[:6]] == ["base", "shoulder", "elbow", "wrist_roll", "wrist_pitch",
                                                    "flange"]
    assert "rigid, 8 kg" in bodies[0] and "massless connector" in bodies[3] and "massless connector" in bodies[4]
    assert "origin [0, 0, 0.4]" in bodies[1] and "elastic (8000 N m/rad)" in bodies[2]
    assert bodies[6].startswith("tool frame: origin [0.1, 0, 0]")
    assert len(info["coordinates"]) == 13 and "elbow.theta" in info["coordinates"]
    for link in ("column", "upper_arm", "forearm", "wrist_1", "wrist_2", "tool"):
        assert any(f'link "{link}"' in t for t in info["terms"]), link
    text = format_explanation(info)
    assert "joints and the bodies they drive" in text and "13 coordinates" in text
