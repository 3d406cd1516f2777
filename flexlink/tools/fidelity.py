"""The fidelity ladder (issue 6, "only what the scene needs"): one arm at several model levels, measured.

The same arm at several model levels, the error each level leaves and what its FMU costs, so that ``flexlink
explain --error-target`` can recommend the cheapest level that is accurate enough.

A level changes the model, never the arm: the shape count (the same on every link), the kinematics, the
deformation fields.  The truth is the top level (most shapes, second-order, the scene's deformation).  The model
error compares a level's equations with the truth's, both under CVODES over the bench manoeuvre (+τ, −τ, free;
or the scene's law): truncation alone.  A user runs the FMU at a step, though, and at the step ``flexlink
explain`` recommends (20 per period of the highest mode) the well-resolved lowest mode still drifts in phase
over many periods, so the FMU's own error against the truth is measured too and, with a target, the step halved
until it meets it.  The cost is measured there, as ``flexlink bench`` times the FMU.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from flexlink.errors import FlexlinkError
from flexlink.scene.loader import Scene, load_scene
from flexlink.scene.schema import Link

if TYPE_CHECKING:                      # imported where used: the ladder loads the model and bench lazily
    from flexlink.mechanics.model import SymbolicModel
    from flexlink.tools.bench import BenchCase

Progress = Callable[[str], None]       # told what is being measured, for a long run's progress line

COUNTS = (1, 2, 3, 4, 6)               # shapes per link (modes, polynomials or elements)
QUICK_COUNTS = (1, 2, 3)
KINEMATICS = ("linear", "first-order", "second-order")
MAX_HALVINGS = 5                       # with a target: steps down to 1/32 of the recommended one
STEPS_PER_PERIOD = 20                  # the recommended step; Θ = ½: phase error per period ≈ (2π/20)²/12 · 2π ≈ 0.5 %
REFERENCE_RTOL = 1e-10                 # CVODES: its own error is far below the model errors measured
SHAPE_WORDS = {"clamped-free": "clamped-free mode", "polynomial": "polynomial", "fe": "element"}


@dataclass(frozen=True)
class Level:
    """One model level of an arm: what changes the model, never the arm.

    Attributes
    ----------
    count : int
        Shapes per link (modes, polynomials or elements; the same on every link).
    kinematics : str
        ``linear``, ``first-order`` or ``second-order``.
    deformation : tuple of str
        The fields kept; each link keeps those of its own it has.
    """

    count: int
    kinematics: str
    deformation: tuple[str, ...]

    def label(self, scene: Scene) -> str:
        """The level in words for the report (``3 modes per link, second-order, v+w``), in the scene's terms."""
        kinds = sorted({link.shapes.kind for link in scene.links})
        word = SHAPE_WORDS.get(kinds[0], "shape") if len(kinds) == 1 else "shape"
        if all(_reduced(link) for link in scene.links):
            word = "mode"
        plural = "" if self.count == 1 else "s"
        per_link = " per link" if len(scene.links) > 1 else ""
        return f"{self.count} {word}{plural}{per_link}, {self.kinematics}, {'+'.join(self.deformation)}"


@dataclass
class Rung:
    """One level of the ladder, measured."""

    level: Level
    label: str
    coordinates: int
    highest_hz: float
    step: float                         # SS22 step, s (explain's recommendation for this level)
    model_error: float                  # CVODES(level) against CVODES(truth)
    integration_error: float            # SS22 FMU at ``step`` against CVODES(level)
    error: float                        # SS22 FMU at ``step`` against CVODES(truth): what a user sees
    cpu_s_per_simulated_s: float
    truth: bool = False
    scene_level: bool = False           # the scene's own setting

    def as_dict(self) -> dict[str, Any]:
        """The rung as JSON-ready values (``flexlink explain --json``)."""
        return {"level": self.label, "count": self.level.count, "kinematics": self.level.kinematics,
                "deformation": list(self.level.deformation), "coordinates": self.coordinates,
                "highest_hz": self.highest_hz, "step": self.step, "model_error": self.model_error,
                "integration_error": self.integration_error, "error": self.error,
                "cpu_s_per_simulated_s": self.cpu_s_per_simulated_s, "truth": self.truth,
                "scene_level": self.scene_level}


@dataclass
class Ladder:
    """A scene's measured ladder: its rungs cheapest first, the truth among them, and what limits the figures.

    ``reference_error`` is the truth's CVODES run against one at 1/10 of its tolerance: errors below it are
    not resolved.  ``notes`` says which levels were left out and why.
    """

    scene: str
    outputs: list[str]
    stop_time: float
    rungs: list[Rung]                   # cheapest first
    reference_error: float              # the truth's CVODES run against one at 1/10 of its tolerance
    target: float | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def truth(self) -> Rung:
        """The top level, every other rung's reference."""
        return next(r for r in self.rungs if r.truth)


# ------------------------------------------------------------------------------------------- the levels

def deformation_levels(scene: Scene) -> list[tuple[str, ...]]:
    """Planar, then (when the scene has torsion and out-of-plane bending) bending only, then the scene's set."""
    union = tuple(f for f in ("v", "w", "alpha") if any(f in link.deformation for link in scene.links))
    if any(link.is_shell for link in scene.links):
        return [union]                      # a shell's modes deform in every direction
    out = [("v",), ("v", "w"), union] if {"w", "alpha"} <= set(union) else [("v",), union]
    out = [d for d in dict.fromkeys(out) if all(set(d) & set(link.deformation) for link in scene.links)]
    return out


def _reduced(link: Link) -> bool:
    """A link whose ladder counts modes (a shell, or an FE beam reduced with ``shapes.modes``)."""
    return link.is_shell or link.shapes.modes is not None


def _max_modes(link: Link) -> int:
    """Modes a reduced link has: translations off the root (a shell), two per element (a Hermite beam)."""
    s = link.shapes
    if link.is_shell:
        return 3 * s.mesh[0] * (2 * (s.mesh[1] + s.mesh[2]) if s.section == "box" else s.mesh[1] + 1)
    return 2 * s.count


def shape_count(link: Link) -> int:
    """The link's own count on the ladder's scale, so that the scene's own level is one of the rungs.

    Its modes when reduced (all of them if not limited), else its shape functions or elements.
    """
    if not _reduced(link):
        return link.shapes.count
    return link.shapes.modes or _max_modes(link)


def top_kinematics(scene: Scene) -> str:
    """Second order, unless a shell link has no such model (its element has no large-deflection strain)."""
    return "first-order" if any(link.is_shell for link in scene.links) else "second-order"


def levels(scene: Scene, counts: Sequence[int] | None = None, kinematics: Sequence[str] | None = None,
           quick: bool = False) -> list[Level]:
    """Counts × kinematics with the scene's deformation, the levels the ladder measures.

    The scene's own count is always one of them, so that the ladder says what the scene as written costs; the
    largest is the truth's.  A count a reduced link cannot have (more modes than coordinates) is left out, and
    second order only where every link has it.

    Raises
    ------
    FlexlinkError
        For a count below 1.
    """
    chosen = sorted(set(counts or (QUICK_COUNTS if quick else COUNTS)) | {shape_count(scene.links[0])})
    chosen = [n for n in chosen if all(n <= _max_modes(link) for link in scene.links if _reduced(link))]
    if chosen[0] < 1:
        raise FlexlinkError(f"shape counts must be positive, got {chosen}")
    top = top_kinematics(scene)
    orders = [k for k in (kinematics or KINEMATICS) if k != "second-order" or top == "second-order"]
    if top not in orders:
        orders.append(top)
    return [Level(n, k, deformation_levels(scene)[-1]) for k in orders for n in chosen]


def variant(scene: Scene, level: Level) -> Scene:
    """The scene's arm modelled at ``level`` (a distinct FMU identifier, so that variants can coexist)."""
    links = tuple(dataclasses.replace(link, shapes=dataclasses.replace(link.shapes, modes=level.count)
                                      if _reduced(link) else dataclasses.replace(link.shapes, count=level.count),
                                      kinematics=level.kinematics,
                                      deformation=tuple(f for f in link.deformation if f in level.deformation))
                  for link in scene.links)
    tag = f"{level.count}_{level.kinematics[0]}_{''.join(f[0] for f in level.deformation)}"
    return dataclasses.replace(scene, links=links, model_identifier=f"{scene.model_identifier}_{tag}")


# ---------------------------------------------------------------------------------------- measurements

def variant_fmu(scene: Scene, model: SymbolicModel | None = None) -> Path:
    """The variant's FMU from the flexlink cache, keyed on the scene's content (it has no file of its own)."""
    from flexlink.export.cache import cached_fmu

    return cached_fmu(scene, model=model)


def recommended_step(model: SymbolicModel) -> tuple[float, float]:
    """(step, highest frequency in Hz) as ``flexlink explain`` gives them."""
    from flexlink.mechanics.analysis import natural_frequencies

    freqs = natural_frequencies(model).frequencies_hz
    f_max = max(freqs) if freqs else 0.0
    return (1.0 / (STEPS_PER_PERIOD * f_max) if f_max > 0 else model.scene.fmu.solver.step), f_max


class _Runs:
    """One level's FMU: its outputs at the case's samples, and its cost.

    The cost is timed as in ``flexlink bench``: one fmi2DoStep per input switch, median of ``repeats`` runs,
    CPU seconds per simulated second.
    """

    def __init__(self, case: BenchCase, fmu: Path):
        from flexlink.run.simulate import SlaveRunner

        self.case = case
        self.runner = SlaveRunner(fmu, instance_name="fidelity")

    def outputs(self, step: float) -> dict[str, np.ndarray]:
        case = self.case
        return self.runner.run(case.stop, float(case.times[1] - case.times[0]), inputs=case.inputs_at,
                               start={"solver.step": step}, outputs=case.outputs)

    def cost(self, step: float, repeats: int) -> float:
        from flexlink.tools.bench import time_slave

        return time_slave(self.runner, self.case, {"solver.step": step}, repeats)

    def close(self) -> None:
        self.runner.close()


@dataclass
class _Measured:
    """A level after its CVODES run (phase 1); its FMU is run and timed in phase 2."""

    level: Level
    case: BenchCase                     # its model dropped (None): phase 2 reads only the manoeuvre
    ref: dict[str, np.ndarray]
    fmu: Path
    n_q: int
    step: float
    f_max: float
    model_error: float = 0.0


def _measure(scene: Scene, level: Level, stop: float, progress: Progress) -> _Measured:
    from flexlink.mechanics.model import build_model
    from flexlink.tools.bench import default_case, reference_outputs

    progress(f"fidelity: {level.label(scene)}")
    sc = variant(scene, level)
    model = build_model(sc)
    case = default_case(model, stop=stop)
    ref = reference_outputs(case, REFERENCE_RTOL)
    step, f_max = recommended_step(model)
    fmu = variant_fmu(sc, model)
    # the case keeps no model: the CasADi graphs of every level would otherwise stay alive through phase 2,
    # which reads only the manoeuvre (times, inputs, outputs); BenchCase types the model it needs to be built
    dropped = dataclasses.replace(case, model=None)  # type: ignore[arg-type]
    return _Measured(level, dropped, ref, fmu, model.n_q, step, f_max)


def _fmu_rung(m: _Measured, runs: _Runs, truth: _Measured, target: float | None, best_cost: float,
              repeats: int) -> tuple[float, dict[str, np.ndarray], float]:
    """A level's FMU at its step, the step halved while a target needs it: ``(step, outputs, cost)``.

    Only a level whose equations meet the target is refined, since no step can make up for a model error; and
    not past the cheapest rung already meeting it, which it could no longer undercut.
    """
    from flexlink.tools.bench import relative_error

    step = m.step
    y = runs.outputs(step)
    cost = runs.cost(step, repeats)
    if target is not None and m.model_error < target:
        for _ in range(MAX_HALVINGS):
            # halving the step at least doubles the steps; the cost per step falls at most by half (fewer
            # Newton iterations): past the cheapest rung meeting the target, this one cannot be recommended
            if relative_error(m.case, y, truth.ref) < target or cost * m.step / step > best_cost:
                break
            before = relative_error(m.case, y, m.ref)
            step /= 2
            y = runs.outputs(step)
            if relative_error(m.case, y, m.ref) > before / 1.5:     # not converging (order ≥ 1): stop
                break
        if step != m.step:
            cost = runs.cost(step, repeats)
    return step, y, cost


def run_ladder(scene_path: str | os.PathLike[str] | Scene, *, target: float | None = None, quick: bool = False,
               counts: Sequence[int] | None = None, kinematics: Sequence[str] | None = None,
               stop: float | None = None, repeats: int | None = None, progress: Progress | None = None) -> Ladder:
    """Measure the scene's ladder (``quick``: counts 1–3 and the scene's, 2.5 s, one timing run, for CI).

    Every count × kinematics with the scene's deformation; a smaller deformation set only at the truth's count
    and kinematics (its best rung), and, when that meets ``target``, at every count × kinematics too.  With a
    target, a rung whose model error meets it has its step halved (at most MAX_HALVINGS times, and not once
    its cost would pass the cheapest rung already meeting the target) until its error meets it too.

    Raises
    ------
    FlexlinkError
        For a bad target, or a scene with no manoeuvre to measure (a free first joint, or a position-driven
        one without a built-in law).
    """
    from flexlink.tools.bench import relative_error

    if target is not None:
        check_target(target)
    progress = progress or (lambda message: None)
    scene = load_scene(scene_path) if not isinstance(scene_path, Scene) else scene_path
    first = scene.joints[0]
    if first.drive == "free" or (first.drive == "position" and first.trajectory is None):
        raise FlexlinkError(f'the fidelity ladder needs a manoeuvre: joint "{first.name}" must be torque-driven '
                            "(+tau, -tau, then free) or position-driven by a built-in trajectory")
    stop = stop or (2.5 if quick else 5.0)
    repeats = repeats or (1 if quick else 3)
    deformations = deformation_levels(scene)
    factorial = levels(scene, counts, kinematics, quick)
    top = Level(max(lv.count for lv in factorial), top_kinematics(scene), deformations[-1])

    # phase 1: every level's equations under CVODES, against the truth's
    truth = _measure(scene, top, stop, progress)
    measured = {top: truth}
    notes: list[str] = []

    def add(lv: Level) -> None:
        try:
            m = _measure(scene, lv, stop, progress)
        except (FlexlinkError, RuntimeError) as e:        # a level the model or CVODES cannot run: say so, go on
            notes.append(f"{lv.label(scene)} left out: {str(e).splitlines()[0]}")
            return
        m.model_error = relative_error(truth.case, m.ref, truth.ref)
        measured[lv] = m

    for d in deformations[:-1]:
        add(Level(top.count, top.kinematics, d))
    for lv in dict.fromkeys(dataclasses.replace(lv, deformation=d) for d in deformations for lv in factorial):
        best_of_d = measured.get(Level(top.count, top.kinematics, lv.deformation))
        full = lv.deformation == deformations[-1]
        if lv not in measured and (full or (target is not None and best_of_d and best_of_d.model_error < target)):
            add(lv)

    # phase 2: each level's FMU at its step, the cheaper (fewer coordinates, simpler kinematics) first
    order = sorted(measured.values(), key=lambda m: (m.n_q, KINEMATICS.index(m.level.kinematics)))
    best_cost = math.inf
    rungs = []
    own = Level(shape_count(scene.links[0]), scene.links[0].kinematics, deformations[-1])
    for m in order:
        progress(f"fidelity: SS22 FMU of {m.level.label(scene)}")
        runs = _Runs(m.case, m.fmu)
        try:
            step, y, cost = _fmu_rung(m, runs, truth, target, best_cost, repeats)
        finally:
            runs.close()
        error = relative_error(m.case, y, truth.ref)
        if target is not None and m.model_error < target and error < target:
            best_cost = min(best_cost, cost)
        rungs.append(Rung(m.level, m.level.label(scene), m.n_q, m.f_max, step, model_error=m.model_error,
                          integration_error=relative_error(m.case, y, m.ref), error=error,
                          cpu_s_per_simulated_s=cost, truth=m.level == top, scene_level=m.level == own))
    rungs.sort(key=lambda r: r.cpu_s_per_simulated_s)
    reference_error = relative_error(truth.case, truth.ref, _truth_check(scene, top, stop))
    if all(np.sqrt(np.mean(truth.ref[n] ** 2)) == 0 for n in truth.ref):
        notes.append("the manoeuvre leaves the outputs at zero: every level is exact for it")
    return Ladder(scene.name, list(truth.case.outputs), stop, rungs, reference_error, target, notes)


def _truth_check(scene: Scene, top: Level, stop: float) -> dict[str, np.ndarray]:
    """The truth's CVODES run at 1/10 of the tolerance (as ``flexlink bench`` checks its reference)."""
    from flexlink.mechanics.model import build_model
    from flexlink.tools.bench import default_case, reference_outputs

    return reference_outputs(default_case(build_model(variant(scene, top)), stop=stop), REFERENCE_RTOL / 10)


def check_target(target: float) -> float:
    """The error target as a float, refused in one line unless a positive finite number (a relative RMS error).

    Checked before the ladder's minutes of work, not after.
    """
    if not (isinstance(target, int | float) and math.isfinite(target) and target > 0):
        raise FlexlinkError(f"--error-target must be a positive number (a relative RMS error), got {target}")
    return float(target)


def recommend(ladder: Ladder, target: float) -> Rung | None:
    """The cheapest rung that meets ``target`` by its model error and by its error at its step (None if none)."""
    check_target(target)
    return next((r for r in ladder.rungs if r.model_error < target and r.error < target), None)


# ---------------------------------------------------------------------- the recommendation, checked directly

CHECK_SWITCHES = (0.7, 1.4)          # the check manoeuvre: +τ for 0.7 s, −τ for 0.7 s, then free
MAX_CHECKS = 3                       # candidates checked before saying that none holds


@dataclass
class Check:
    """A level's FMU at its step against the truth under CVODES, on a manoeuvre the ladder did not choose on."""

    label: str
    manoeuvre: str
    errors: dict[str, float]          # per output: RMS deviation / RMS of the truth
    error: float                      # the largest: what is compared with the target
    passed: bool

    def as_dict(self) -> dict[str, Any]:
        """The check as JSON-ready values (``flexlink explain --json``)."""
        return {"level": self.label, "manoeuvre": self.manoeuvre, "errors": self.errors, "error": self.error,
                "passed": self.passed}


def check_case(case: BenchCase) -> tuple[BenchCase, str]:
    """The ladder's manoeuvre with other switch times (a torque-driven first joint), and its description.

    So that a level whose model and integration errors happened to cancel on the ladder's manoeuvre is not
    recommended on that luck; a position-driven joint has one manoeuvre, its built-in law: the check then
    repeats it, afresh.
    """
    if not case.switches:
        return case, "the built-in law (the only manoeuvre of a position-driven first joint)"
    (name, torque), = case.pieces[0][1].items()
    t1, t2 = CHECK_SWITCHES
    pieces = [(0.0, {name: torque}), (t1, {name: -torque}), (t2, {name: 0.0})]
    return (dataclasses.replace(case, pieces=pieces, switches=[t for t in (t1, t2) if t < case.stop]),
            f"{name} = {torque:g} for {t1:g} s, {-torque:g} for {t2 - t1:g} s, then 0")


def check_level(scene: Scene, rung: Rung, truth_level: Level, stop: float, target: float,
                progress: Progress | None = None) -> Check:
    """Check a recommended rung directly: its FMU on the check manoeuvre against the truth's equations.

    ``rung``'s FMU (a fresh instance) runs at its SS22 step over the check manoeuvre and each output is
    compared with the truth's equations under CVODES on the same manoeuvre: the error measured directly, with
    no part of it taken from the ladder.
    """
    from flexlink.mechanics.model import build_model
    from flexlink.run.simulate import SlaveRunner
    from flexlink.tools.bench import default_case, reference_outputs

    (progress or (lambda m: None))(f"fidelity: checking {rung.label} on a second manoeuvre")
    truth_case, manoeuvre = check_case(default_case(build_model(variant(scene, truth_level)), stop=stop))
    ref = reference_outputs(truth_case, REFERENCE_RTOL)
    with SlaveRunner(variant_fmu(variant(scene, rung.level)), instance_name="fidelity_check") as runner:
        y = runner.run(stop, float(truth_case.times[1] - truth_case.times[0]), inputs=truth_case.inputs_at,
                       start={"solver.step": rung.step}, outputs=truth_case.outputs)
    errors = {n: float(np.sqrt(np.mean((y[n] - ref[n]) ** 2)) / max(np.sqrt(np.mean(ref[n] ** 2)), 1e-300))
              for n in truth_case.outputs}
    error = max(errors.values())
    return Check(rung.label, manoeuvre, errors, error, error < target)


def checked_recommendation(candidates: list[Rung], check: Callable[[Rung], Check]
                           ) -> tuple[Rung | None, list[Check]]:
    """The cheapest of ``candidates`` whose direct ``check(rung)`` passes, and every check made.

    ``candidates`` are cheapest first, each meeting the target on the ladder; at most MAX_CHECKS are tried, a
    check costing a full run.  Returns the rung (None if none passed) and every check.
    """
    checks = []
    for rung in candidates[:MAX_CHECKS]:
        checks.append(check(rung))
        if checks[-1].passed:
            return rung, checks
    return None, checks
