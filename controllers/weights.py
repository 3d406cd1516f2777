"""The LQR's weights from the command line: Bryson limits per joint, link and mode, torque limits per joint.

``flexlink control`` takes them as ``--joint-error``, ``--tip-deflection``, ``--root-moment``, ``--mode-limit``
and ``--torque-limit`` (:func:`controllers.options.limits` parses the syntax).  This module turns them into what
:func:`controllers.design.bryson_weights` takes — FMU output name → largest acceptable deviation, SI — laid over
the defaults of :func:`controllers.design.default_limits`, and refuses in one line a joint, link or mode the
scene does not have.  The names are the scene's: joints and links by name, a mode as its output
``<link>.eta[k]``.

The checks come in two passes, so that a misspelt name costs no model build: :func:`check_names` on the scene
(joints, links), :func:`overrides` on the built model (which joints have an encoder, which links a tip deflection
or a root moment output, how many modes each link has).
"""

from __future__ import annotations

import math
import re

from flexlink.errors import FlexlinkError

__all__ = ["OPTIONS", "bryson_limits", "check_names", "describe", "overrides", "torque_limits"]

#: option → (what it limits, the output name of one item, its command-line unit's factor to SI: deg, mm, N m).
OPTIONS = {
    "joint_error": ("joint", "{}.theta", math.pi / 180.0),
    "tip_deflection": ("link", "{}.tip.v", 1e-3),
    "root_moment": ("link", "{}.root.moment", 1.0),
    "mode_limit": ("mode", "{}", 1.0),
}

_MODE = re.compile(r"^(?P<link>.+)\.eta\[(?P<k>\d+)\]$")


def _link_of(mode: str) -> str:
    """The link of a mode's name ``<link>.eta[k]``; the name itself when it is a link's."""
    m = _MODE.match(mode)
    return m.group("link") if m else mode


def _flag(option: str) -> str:
    return "--" + option.replace("_", "-")


def check_names(scene, args) -> None:
    """Refuse a joint or link name that the scene lacks, before the model is built.

    A mode's name is checked for its link here and for its index by :func:`overrides`.
    """
    joints = [j.name for j in scene.joints]
    links = [lk.name for lk in scene.links]
    torque = [j.name for j in scene.joints if j.drive == "torque"]
    if isinstance(args.torque_limit, dict):
        for name in args.torque_limit:
            if name not in joints:
                raise FlexlinkError(f"--torque-limit: {name!r} is not a joint of the scene (joints: "
                                    f"{', '.join(joints)})")
            if name not in torque:
                drive = next(j.drive for j in scene.joints if j.name == name)
                raise FlexlinkError(f'--torque-limit: joint "{name}" is not torque-driven (drive = "{drive}"): it has '
                                    "no actuator to limit")
        missing = [j for j in torque if j not in args.torque_limit]
        if missing:
            raise FlexlinkError(f"--torque-limit: no limit for the torque-driven joint(s) {', '.join(missing)}")
    for option, (kind, _, _) in OPTIONS.items():
        value = getattr(args, option, None)
        if not isinstance(value, dict):
            continue
        known = joints if kind == "joint" else links
        for name in value:
            owner = name if kind != "mode" else _link_of(name)
            if owner not in known:
                raise FlexlinkError(f"{_flag(option)}: {owner!r} is not a {'joint' if kind == 'joint' else 'link'} "
                                    f"of the scene ({'joints' if kind == 'joint' else 'links'}: {', '.join(known)})")


def overrides(model, args) -> dict[str, float]:
    """The Bryson limits the command line gives, by output name in SI, checked against the built model.

    A single value applies to every joint with an encoder (``--joint-error``), every link with that output
    (``--tip-deflection``, ``--root-moment``) or every mode of every link (``--mode-limit``); a list gives one
    per item in scene order; names give them one by one (a link's name in ``--mode-limit`` gives all its modes).
    What the command line does not name keeps its default (:func:`controllers.design.default_limits`).
    """
    outputs = {s.name for s in model.outputs}
    joints = [j.name for j in model.scene.joints if f"{j.name}.theta" in model.coordinates]
    links = {o: [lk.name for lk in model.scene.links if OPTIONS[o][1].format(lk.name) in outputs]
             for o in ("tip_deflection", "root_moment")}
    modes = {lk.name: [c for c in model.coordinates if c.startswith(f"{lk.name}.eta[") and c in outputs]
             for lk in model.scene.links}
    out: dict[str, float] = {}
    for option, (_, fmt, si) in OPTIONS.items():
        value = getattr(args, option, None)
        if value is None:
            continue
        if option == "joint_error":
            items = _items(option, value, joints, "joints with an encoder")
        elif option == "mode_limit":
            items = _mode_items(value, modes)
        else:
            items = _items(option, value, links[option], f"links with a {OPTIONS[option][1].format('')[1:]} output")
        for name, v in items.items():
            out[fmt.format(name)] = v * si
    return out


def _items(option: str, value, names: list[str], what: str) -> dict[str, float]:
    """Name → value for a per-joint or per-link option: one for all, one each in order, or by name."""
    if isinstance(value, dict):
        for name in value:
            if name not in names:
                raise FlexlinkError(f"{_flag(option)}: {name!r} has nothing to weigh here (the {what}: "
                                    f"{', '.join(names) or 'none'})")
        return dict(value)
    if len(value) == 1:
        return {n: value[0] for n in names}
    if len(value) != len(names):
        raise FlexlinkError(f"{_flag(option)}: one value for all or one per item of the {what} "
                            f"({', '.join(names)}), got {len(value)}")
    return dict(zip(names, value, strict=True))


def _mode_items(value, modes: dict[str, list[str]]) -> dict[str, float]:
    """``--mode-limit``: every mode, a link's modes (``LINK=V``) or one mode (``LINK.eta[K]=V``)."""
    every = [m for ms in modes.values() for m in ms]
    if not isinstance(value, dict):
        if len(value) != 1:
            raise FlexlinkError("--mode-limit: one value for every mode, or LINK=V / LINK.eta[K]=V by name")
        return {m: value[0] for m in every}
    out: dict[str, float] = {}
    for name, v in value.items():
        if name in modes:
            if not modes[name]:
                raise FlexlinkError(f"--mode-limit: link {name!r} is rigid: it has no mode to weigh")
            out.update({m: v for m in modes[name]})
        elif name in every:
            out[name] = v
        else:
            link = _link_of(name)
            have = modes.get(link, [])
            raise FlexlinkError(f"--mode-limit: {name!r} is not a mode of the model (link {link!r} has "
                                f"{', '.join(have) if have else 'no mode'})")
    return out


def bryson_limits(model, weights) -> dict[str, float]:
    """:func:`overrides` of the options given as a mapping (``flexlink sweep``'s settings: option → value).

    Empty without any: the design's defaults.
    """
    from types import SimpleNamespace

    weights = weights or {}
    return overrides(model, SimpleNamespace(**{name: weights.get(name) for name in OPTIONS}))


def torque_limits(plant, values):
    """``--torque-limit`` as the design takes it: one number, or a mapping joint → limit.

    One value (a number, or a list of one) is every joint's limit; several are one per torque-driven joint, in
    order; a mapping is by name (checked by :func:`check_names`).  None when not given (the design then derives a
    limit from the manoeuvre).
    """
    from controllers.design import actuated_joints

    if values is None or isinstance(values, dict | float | int):
        return values
    if len(values) == 1:
        return values[0]
    joints = actuated_joints(plant)
    if len(values) != len(joints):
        raise FlexlinkError(f"--torque-limit: one limit for all joints or one per torque-driven joint "
                            f"({', '.join(joints)}), got {len(values)}")
    return dict(zip(joints, values, strict=True))


def describe(limits: dict[str, float]) -> str:
    """The Bryson limits in the command line's units, one ``name value unit`` each (``--design-only``'s line)."""
    def one(name: str, v: float) -> str:
        if name.endswith(".theta"):
            return f"{name} {math.degrees(v):.4g} deg"
        if name.endswith(".tip.v"):
            return f"{name} {1e3 * v:.4g} mm"
        if name.endswith(".root.moment"):
            return f"{name} {v:.4g} N m"
        return f"{name} {v:.4g}"
    return ", ".join(one(k, v) for k, v in limits.items())
