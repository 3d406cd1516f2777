"""The deformed centre line of a chain, for drawing it: points along every link from the coordinates.

The FMU reports the joint angles and the elastic coordinates η of every link, and the tool's position, but
not the shape of a link between its root and its tip. That shape is what the model itself assumes: the
section at abscissa x of a beam link sits at ``s(x) = (x + u(x), v(x), w(x))`` in the link's frame, with
``v = φ(x)·η_v``, ``w = φ(x)·η_w`` from the link's shape functions and, in second-order kinematics, the
foreshortening ``u = −½ ηᵀ(∫₀ˣ φ'φ'ᵀ)η`` (:mod:`flexlink.mechanics.kinematics`). So the drawing re-uses the
chain's own frames (:class:`flexlink.mechanics.assembly.ChainAssembly`) and evaluates s(x) at a few points;
at the tip it is exactly the model's tip, so the drawn end of the arm is the FMU's ``tip.x/y/z``.

What is not drawn: torsion (it turns the sections, not the centre line); a shell link (plate, box section)
is drawn as the straight segment from its root to its tip point, since its modes deform a surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import numpy.typing as npt

from flexlink.mechanics.assembly import ChainAssembly, Frame, LinkParts
from flexlink.mechanics.shapes.base import ShapeBasis
from flexlink.scene.loader import Link, Scene

POINTS_PER_LINK = 21


@dataclass
class Centreline:
    """The drawing of a chain: ``points(qa) -> (n, 3)``, its joint origins, link sections and tool point.

    The points are in the world frame; ``joints`` and ``payloads`` index the joint origins and payload points
    among them, and ``polyline`` those drawn as the arm's line.
    """

    coordinates: list[str]      # the full coordinate vector, named as the FMU's outputs
    elastic: np.ndarray         # boolean mask of the elastic coordinates η in it
    function: ca.Function       # (qa) -> 3 × n
    joints: list[int]
    payloads: list[int]
    polyline: list[int]         # the indices drawn as the arm's line (payload points are off it)

    def points(self, qa: npt.ArrayLike) -> np.ndarray:
        """The world positions (n, 3) of the drawn points for the coordinate vector ``qa`` (joints and η)."""
        return np.asarray(self.function(np.asarray(qa, float))).T


def _foreshortening(basis: ShapeBasis, xs: np.ndarray, fs_tip: np.ndarray) -> list[np.ndarray]:
    """∫₀ˣ φ'φ'ᵀ at each x of ``xs`` (a fine trapezoid; the tip's exact matrix at x = L)."""
    fine = np.linspace(0.0, basis.length, 2001)
    d1 = basis.evaluate(fine, 1)
    outer = d1[:, :, None] * d1[:, None, :]
    steps = 0.5 * (outer[1:] + outer[:-1]) * np.diff(fine)[:, None, None]
    cumulative = np.concatenate([np.zeros((1, *outer.shape[1:])), np.cumsum(steps, axis=0)])
    out = [np.array([[np.interp(x, fine, cumulative[:, a, b]) for b in range(basis.n)] for a in range(basis.n)])
           for x in xs]
    out[-1] = np.asarray(fs_tip)
    return out


def _link_sections(chain: ChainAssembly, i: int, link: Link, part: LinkParts, frame: Frame) -> list[ca.MX]:
    """Points s(x) of link i in the world (its root excluded), from its frame and coordinates."""
    qa = chain.qa
    if part.rigid or part.body is not None:
        return [frame.tip_origin]
    xs = np.linspace(0.0, link.length, POINTS_PER_LINK)[1:]
    d = chain.deformation(part, qa, chain.va)
    phi = part.bending.evaluate(xs) if part.bending is not None else None
    fs = (_foreshortening(part.bending, xs, part.bending.integrals.fs_tip)
          if part.bending is not None and part.second_order else None)
    points: list[ca.MX] = []
    for k, x in enumerate(xs):
        s: list[float | ca.MX] = [x, 0, 0]
        for axis, eta in ((1, d.v), (2, d.w)):
            if eta is None:
                continue
            assert phi is not None, "a link with v or w coordinates has a bending basis (assembly.py)"
            s[axis] = ca.dot(ca.DM(phi[k]), eta)
            if fs is not None:
                s[0] = s[0] - 0.5 * ca.dot(eta, ca.mtimes(ca.DM(fs[k]), eta))
        points.append(frame.origin + ca.mtimes(frame.rotation, ca.vertcat(*s)))
    points[-1] = frame.tip_origin            # the model's own tip (identical up to round-off)
    return points


def centreline(scene: Scene) -> Centreline:
    """The chain's drawing function, assembled from the same frames as the model (no equations formed)."""
    chain = ChainAssembly(scene)
    chain.assemble_kinematics()
    p0 = ca.DM([par.value for par in chain.P.items])
    points: list[ca.MX] = []
    joints: list[int] = []
    payloads: list[int] = []
    polyline: list[int] = []
    for i, (link, part, frame) in enumerate(zip(scene.links, chain.parts, chain.frames, strict=True)):
        joints.append(len(points))
        polyline.append(len(points))
        points.append(chain.joint_frames[i][0])
        for p in _link_sections(chain, i, link, part, frame):
            polyline.append(len(points))
            points.append(p)
        if part.i_pm is not None:                   # the payload the model has (mass or inertia > 0)
            payloads.append(len(points))
            points.append(frame.tip_origin + ca.mtimes(frame.tip_rotation, ca.DM(np.asarray(link.payload.offset))))
    if chain.tool is not chain.frames[-1]:
        polyline.append(len(points))
        points.append(chain.tool.tip_origin)
    expr = ca.substitute(ca.horzcat(*points), chain.p, p0)
    function = ca.Function("centreline", [chain.qa], [ca.densify(expr)])
    elastic = np.array([kind == "elastic" for kind in chain.kinds])
    return Centreline(list(chain.coordinates), elastic, function, joints, payloads, polyline)
