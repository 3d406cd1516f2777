"""An independent model of examples/fast_two_link.toml in Exudyn (geometrically exact 2D beams).

The same arm as flexlink's scene, built from Exudyn's own items:

* each link is ``n_elements`` ``ObjectBeamGeometricallyExact2D`` (Simo–Reissner, two ``NodeRigidBody2D`` per
  element, linear interpolation); made Euler–Bernoulli by a large axial and shear stiffness (``EA``, ``GA``,
  default 1e9 N, 55× the real aluminium section's EA: from 1e8 to 1e9 N the tip deflections move by 3e-4 and
  6e-4 of their amplitude over 2 s, from 1e9 to 1e10 N by 4e-5 and 1.3e-4, the joint angles by < 1e-6) and no
  rotary inertia of the sections (``rotary``, default 0: Euler–Bernoulli has none; the change is linear in it,
  and the real section's ρI ≈ 8.5e-5 kg m would move the joint angles by 3e-4 and 5e-4 of their amplitude);
* the rotor of each joint is an ``ObjectRigidBody2D`` (mass 0, inertia ``J``) on the root node of its link, so
  the beam is clamped to the hub (node rotation = hub rotation = joint frame);
* the shoulder is an ``ObjectJointRevolute2D`` between the ground and link 1's root node; the elbow one between
  link 1's tip node and link 2's root node (two nodes at one point, rotations free);
* the torques are ``LoadTorqueVector`` with user functions: τ₁ on link 1's root node; τ₂ on link 2's root node
  and −τ₂ on link 1's tip node (the elbow motor reacts on link 1's tip);
* the payload is an ``ObjectRigidBody2D`` of mass 1.5 kg and inertia 0 on link 2's tip node.

Outputs, as flexlink defines them (docs/chains.md): ``shoulder.theta`` = rotation of link 1's root node;
``elbow.theta`` = rotation of link 2's root node − rotation of link 1's tip node (the joint sits on link 1's tip
frame, which turns with its tip slope); ``<link>.tip.v`` = the tip position relative to the link's root node,
expressed in the root node's frame, its component normal to the root tangent.

Time integration: Exudyn's generalised-α (index-3 constraints, spectral radius ``rho_inf``), constant step
``step``, Newton until the increment of the coordinates is below ``tolerance`` (1e-10 m or rad; 1e-12 changes
nothing above 1e-6 of the amplitudes). A residual criterion does not work here: the rounding of the stiff axial
forces (∝ EA·N) keeps the residual above any fixed tolerance at EA = 1e9, N = 64.
"""

from __future__ import annotations

import math
import time

import numpy as np

ARM = {
    "length": 1.0, "linear_density": 0.7, "EI": 2204.0,
    "inertia": (0.1, 0.05), "payload": 1.5,
}


def torques(t: float) -> tuple[float, float]:
    """τ₁ = 40 sin 2πt, τ₂ = 10 sin 2πt for t < 1 s, 0 afterwards."""
    if t >= 1.0:
        return 0.0, 0.0
    s = math.sin(2.0 * math.pi * t)
    return 40.0 * s, 10.0 * s


def simulate(n_elements: int = 32, step: float = 1e-4, stop: float = 2.0, *, output_step: float = 1e-3,
             EA: float = 1e9, GA: float = 1e9, rotary: float = 0.0, rho_inf: float = 0.9,
             tolerance: float = 1e-10, torque=torques, sparse: bool = True, verbose: int = 0) -> dict[str, np.ndarray]:
    """Run the Exudyn arm; returns ``{"time", "shoulder.theta", "elbow.theta", "upper.tip.v", "fore.tip.v",
    "tip.x", "tip.y", "cpu"}`` sampled every ``output_step`` (``cpu``: process time of the solve, seconds)."""
    import exudyn as exu
    from exudyn.itemInterface import (
        LoadTorqueVector,
        MarkerBodyPosition,
        MarkerNodePosition,
        MarkerNodeRigid,
        NodeRigidBody2D,
        ObjectBeamGeometricallyExact2D,
        ObjectGround,
        ObjectJointRevolute2D,
        ObjectRigidBody2D,
        SensorNode,
    )

    L, rhoA, EI = ARM["length"], ARM["linear_density"], ARM["EI"]
    le = L / n_elements
    SC = exu.SystemContainer()
    mbs = SC.AddSystem()

    links = []
    for k in range(2):
        x0 = k * L
        nodes = [mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[x0 + i * le, 0.0, 0.0]))
                 for i in range(n_elements + 1)]
        for i in range(n_elements):
            mbs.AddObject(ObjectBeamGeometricallyExact2D(
                nodeNumbers=[nodes[i], nodes[i + 1]], length=le, massPerLength=rhoA, crossSectionInertia=rotary,
                bendingStiffness=EI, axialStiffness=EA, shearStiffness=GA))
        mbs.AddObject(ObjectRigidBody2D(mass=0.0, inertia=ARM["inertia"][k], nodeNumber=nodes[0]))
        links.append(nodes)
    mbs.AddObject(ObjectRigidBody2D(mass=ARM["payload"], inertia=0.0, nodeNumber=links[1][-1]))

    ground = mbs.AddObject(ObjectGround(referencePosition=[0.0, 0.0, 0.0]))
    m_ground = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0.0, 0.0, 0.0]))
    m_root1 = mbs.AddMarker(MarkerNodePosition(nodeNumber=links[0][0]))
    m_tip1 = mbs.AddMarker(MarkerNodePosition(nodeNumber=links[0][-1]))
    m_root2 = mbs.AddMarker(MarkerNodePosition(nodeNumber=links[1][0]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[m_ground, m_root1]))
    mbs.AddObject(ObjectJointRevolute2D(markerNumbers=[m_tip1, m_root2]))

    r_root1 = mbs.AddMarker(MarkerNodeRigid(nodeNumber=links[0][0]))
    r_tip1 = mbs.AddMarker(MarkerNodeRigid(nodeNumber=links[0][-1]))
    r_root2 = mbs.AddMarker(MarkerNodeRigid(nodeNumber=links[1][0]))
    mbs.AddLoad(LoadTorqueVector(markerNumber=r_root1, loadVector=[0.0, 0.0, 1.0],
                                 loadVectorUserFunction=lambda mbs, t, load: [0.0, 0.0, torque(t)[0]]))
    mbs.AddLoad(LoadTorqueVector(markerNumber=r_root2, loadVector=[0.0, 0.0, 1.0],
                                 loadVectorUserFunction=lambda mbs, t, load: [0.0, 0.0, torque(t)[1]]))
    mbs.AddLoad(LoadTorqueVector(markerNumber=r_tip1, loadVector=[0.0, 0.0, -1.0],
                                 loadVectorUserFunction=lambda mbs, t, load: [0.0, 0.0, -torque(t)[1]]))

    watched = {"root1": links[0][0], "tip1": links[0][-1], "root2": links[1][0], "tip2": links[1][-1]}
    sensors = {name: mbs.AddSensor(SensorNode(nodeNumber=n, storeInternal=True, writeToFile=False,
                                              outputVariableType=exu.OutputVariableType.Coordinates))
               for name, n in watched.items()}
    mbs.Assemble()

    s = exu.SimulationSettings()
    ti = s.timeIntegration
    ti.numberOfSteps = int(round(stop / step))
    ti.endTime = stop
    ti.verboseMode = verbose
    ti.adaptiveStep = False
    # Newton converged on the increment of the coordinates (m, rad), not on the residual: the residual's rounding
    # floor grows with EA·N (a fixed residual tolerance is unreachable at EA = 1e9, N = 64)
    ti.newton.residualMode = 1
    ti.newton.relativeTolerance = ti.newton.absoluteTolerance = tolerance
    ti.generalizedAlpha.spectralRadius = rho_inf
    ti.generalizedAlpha.computeInitialAccelerations = False     # at rest, no torque at t = 0
    s.solution.file.write = False
    s.solution.sensors.writePeriod = output_step
    s.show.globalTimers = False
    s.linearSolver.solverType = exu.LinearSolverType.EigenSparse if sparse else exu.LinearSolverType.EXUdense

    cpu = time.process_time()
    mbs.SolveDynamic(s)
    cpu = time.process_time() - cpu

    data = {name: np.asarray(mbs.GetSensorStoredData(sid)) for name, sid in sensors.items()}
    t = data["root1"][:, 0]
    ref = {"root1": (0.0, 0.0), "tip1": (L, 0.0), "root2": (L, 0.0), "tip2": (2 * L, 0.0)}
    pos = {name: np.stack([d[:, 1] + ref[name][0], d[:, 2] + ref[name][1]], axis=1) for name, d in data.items()}
    phi = {name: d[:, 3] for name, d in data.items()}

    def tip_v(root, tip):
        r = pos[tip] - pos[root]
        c, sn = np.cos(phi[root]), np.sin(phi[root])
        return -sn * r[:, 0] + c * r[:, 1]

    return {
        "time": t,
        "shoulder.theta": phi["root1"],
        "elbow.theta": phi["root2"] - phi["tip1"],
        "upper.tip.v": tip_v("root1", "tip1"),
        "fore.tip.v": tip_v("root2", "tip2"),
        "tip.x": pos["tip2"][:, 0],
        "tip.y": pos["tip2"][:, 1],
        "cpu": cpu,
    }


if __name__ == "__main__":
    import sys

    n, h = int(sys.argv[1]), float(sys.argv[2])
    res = simulate(n, h, float(sys.argv[3]) if len(sys.argv) > 3 else 2.0)
    print(f"N = {n}, h = {h}: cpu {res['cpu']:.2f} s")
    for k in ("shoulder.theta", "elbow.theta", "upper.tip.v", "fore.tip.v"):
        print(f"  {k}: max |.| {np.max(np.abs(res[k])):.6g}, final {res[k][-1]:.6g}")
