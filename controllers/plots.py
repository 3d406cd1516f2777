"""Plots of a closed-loop manoeuvre: time responses, closed-loop poles, loop Bode with margins."""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence

import control as ct
import numpy as np

from controllers.closedloop import closed_loop, loop_transfer, margins

__all__ = ["margins_text", "path_margins_text", "plot_loop_bode", "plot_manoeuvre", "plot_multijoint", "plot_poles",
           "plot_time_responses"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_time_responses(axes, results: Sequence, design, predictions: Sequence[dict | None] = ()) -> None:
    """Hub angle (and reference), tip deflection and torque of one or more :class:`ManoeuvreResult`.

    Dashed: the linear closed-loop predictions, when given, so that the FMU's run shows where it leaves the
    linear design.
    """
    joint, link, tau = design.joint, design.link, design.plant.inputs[0]
    preds = list(predictions) + [None] * (len(results) - len(predictions))
    for k, (res, pred) in enumerate(zip(results, preds, strict=True)):
        c = f"C{k}"
        t = res["time"]
        label = f"{res.controller.upper()}"
        axes[0].plot(t, np.degrees(res[f"{joint}.theta"]), c, lw=1.2, label=label)
        axes[0].plot(t, np.degrees(res[f"{joint}.theta_ref"]), c, lw=0.8, ls=":", label=f"{label} reference")
        axes[1].plot(t, 1e3 * res[f"{link}.tip.v"], c, lw=1.2, label=label)
        axes[2].plot(t, res[tau], c, lw=1.0, label=label)
        if pred is not None:
            axes[0].plot(pred["time"], np.degrees(pred[f"{joint}.theta"]), c, lw=0.8, ls="--",
                         label=f"{label} linear prediction")
            axes[1].plot(pred["time"], 1e3 * pred[f"{link}.tip.v"], c, lw=0.8, ls="--")
    lim = design.torque_limit
    axes[2].axhline(lim, color="k", lw=0.6, ls="--")
    axes[2].axhline(-lim, color="k", lw=0.6, ls="--")
    for ax in axes:
        ax.axvline(results[0].duration, color="0.6", lw=0.6)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"{joint}.theta (deg)")
    axes[1].set_ylabel(f"{link}.tip.v (mm)")
    axes[2].set_ylabel(f"{tau} (N m)")
    axes[2].set_xlabel("time (s)")
    axes[0].legend(fontsize=7, loc="lower right")
    axes[1].legend(fontsize=7, loc="upper right")


def plot_poles(ax, design, controllers: Sequence[str] = ("lqr", "pd")) -> None:
    """Closed-loop poles (python-control) mapped to the s-plane, s = ln(z)/dt, rad/s."""
    markers = {"lqr": "x", "pd": "o"}
    for k, name in enumerate(controllers):
        cl = closed_loop(design.plant, design.law(name), [f"{design.joint}.theta"])
        z = cl.poles()
        z = z[np.abs(z) > 1e-12]
        s = np.log(z.astype(complex)) / design.dt
        ax.plot(s.real, s.imag, markers.get(name, "+"), color=f"C{k}", mfc="none", label=f"{name.upper()} closed loop")
    ol = design.plant.sys.poles()
    ax.plot(ol.real, ol.imag, "k+", ms=5, label="open loop")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlabel("Re s (1/s)")
    ax.set_ylabel("Im s (rad/s)")
    ax.axvline(0, color="k", lw=0.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("closed-loop poles, s = ln(z)/dt", fontsize=9)


def plot_loop_bode(ax_mag, ax_phase, design, controllers: Sequence[str] = ("lqr", "pd")) -> dict:
    """Bode plot of the loop transfer at the torque input, L = −C_y P, with its margins.

    The classical margins and the balanced disk margin (``control.disk_margins``, skew 0); returns the
    margins by controller.
    """
    out = {}
    w = np.logspace(-1, np.log10(np.pi / design.dt), 3000)[:-1]
    for k, name in enumerate(controllers):
        law = design.law(name)
        L = loop_transfer(design.plant, law)
        Lw = np.asarray(L.frequency_response(w).complex).ravel()
        m = margins(design.plant, law)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dm, dgm, dpm = ct.disk_margins(L, w, skew=0.0)      # balanced: controllers.robustness.DISK_SKEW
        m = {**m, "disk_margin": float(dm), "disk_gain_margin_db": float(dgm), "disk_phase_margin_deg": float(dpm)}
        out[name] = m
        hz = w / (2 * np.pi)
        ax_mag.semilogx(hz, 20 * np.log10(np.abs(Lw)), f"C{k}", lw=1.0,
                        label=f"{name.upper()}: GM {m['gain_margin_db']:.1f} dB, PM {m['phase_margin_deg']:.0f}°; "
                              f"disk ±{dgm:.1f} dB with ±{dpm:.0f}°")
        phase = np.degrees(np.angle(Lw))
        ax_phase.semilogx(hz, np.where(phase > 0, phase - 360, phase), f"C{k}", lw=1.0)
        if np.isfinite(m["gain_crossover_hz"]):
            ax_mag.axvline(m["gain_crossover_hz"], color=f"C{k}", lw=0.5, ls=":")
    ax_mag.axhline(0, color="k", lw=0.5)
    ax_phase.axhline(-180, color="k", lw=0.5)
    ax_mag.set_ylabel("|L| (dB)")
    ax_phase.set_ylabel("arg L (deg, in (−360, 0])")
    ax_phase.set_yticks([-360, -270, -180, -90, 0])
    ax_phase.set_xlabel("frequency (Hz)")
    ax_mag.legend(fontsize=7)
    ax_mag.set_title("loop broken at the torque input", fontsize=9)
    for ax in (ax_mag, ax_phase):
        ax.grid(alpha=0.3, which="both")
    return out


def plot_manoeuvre(path: str | os.PathLike, results: Sequence, design, predictions: Sequence[dict | None] = (),
                   title: str = "") -> None:
    """One figure: time responses (left), closed-loop poles and loop Bode (right)."""
    plt = _pyplot()
    fig = plt.figure(figsize=(13, 8.5))
    gs = fig.add_gridspec(3, 2, width_ratios=[1.3, 1.0])
    left = [fig.add_subplot(gs[0, 0])]
    left += [fig.add_subplot(gs[i, 0], sharex=left[0]) for i in (1, 2)]
    plot_time_responses(left, results, design, predictions)
    names = list(dict.fromkeys(r.controller for r in results))
    others = [c for c in ("lqr", "pd") if c not in names]
    shown = names + others
    plot_poles(fig.add_subplot(gs[0, 1]), design, shown)
    plot_loop_bode(fig.add_subplot(gs[1, 1]), fig.add_subplot(gs[2, 1]), design, shown)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: The legend's name of each run of a multi-joint comparison.
LABELS = {"lqr": "LQG", "pd": "PD", "fixed": "fixed LQG", "scheduled": "scheduled LQG"}


def plot_multijoint(path: str | os.PathLike, results: dict, title: str = "", robustness: dict | None = None,
                    caption: str | None = None) -> None:
    """Plot the multi-joint comparison (:func:`controllers.multijoint.compare`) to ``path``.

    Joint angles against their references, tracking errors, every link's tip deflection and the torques, LQG and PD,
    the figures of each run (settling time, residual vibration, peak torque) in the legends; with ``robustness`` (a
    loop of :func:`controllers.robustness.robustness_figures`, the sampled LQG's), its margins at each actuator
    under the plot; ``caption`` (lines of text, a scheduled run's margins along the path: :func:`path_margins_text`)
    instead.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(13, 8), sharex=True)
    (a_th, a_err), (a_tip, a_tau) = axes
    styles = ["-", "--", ":", "-."]
    for k, (name, res) in enumerate(results.items()):
        m, s, c = res.metrics, res.series, f"C{k}"
        t = s["time"]
        ts = "not settled" if m["settling_time_s"] is None else f"settles in {m['settling_time_s']:.3g} s"
        lab = LABELS.get(name, name)
        label = f"{lab}: {ts}"
        for i, j in enumerate(m["joints"]):
            ls = styles[i % 4]
            a_th.plot(t, np.degrees(s[f"{j}.theta"]), c, ls=ls, lw=1.1, label=f"{label} ({j})" if i == 0 else j)
            if k == 0:
                a_th.plot(t, np.degrees(s[f"{j}.theta_ref"]), "k", ls=ls, lw=0.6)
            a_err.plot(t, np.degrees(s[f"{j}.theta"] - s[f"{j}.theta_ref"]), c, ls=ls, lw=1.0,
                       label=f"{lab} {j}: final {m['joints'][j]['final_error_deg']:.2g} deg")
            a_tau.plot(t, s[f"{j}.tau"], c, ls=ls, lw=0.9,
                       label=f"{lab} {j}: peak {m['joints'][j]['peak_torque_nm']:.3g} N m")
        for i, (lk, f) in enumerate(m["links"].items()):
            a_tip.plot(t, 1e3 * s[f"{lk}.tip.v"], c, ls=styles[i % 4], lw=1.0,
                       label=f"{lab} {lk}: residual {1e3 * f['residual_vibration_rms_m']:.3g} mm RMS")
    a_th.set_ylabel("joint angle (deg); black: reference")
    a_err.set_ylabel("tracking error (deg)")
    a_tip.set_ylabel("tip.v (mm)")
    a_tau.set_ylabel("torque (N m)")
    for ax in axes.ravel():
        ax.axvline(next(iter(results.values())).duration, color="0.6", lw=0.6)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes[1]:
        ax.set_xlabel("time (s)")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    if caption is None and robustness is not None:
        caption = margins_text(robustness)
    if caption is not None:
        fig.subplots_adjust(bottom=0.09 + 0.017 * (caption.count("\n") + 1))
        fig.text(0.01, 0.01, caption, fontsize=7, family="monospace", va="bottom")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def margins_text(rob: dict) -> str:
    """One line per actuator of a loop's JSON figures, for a plot's caption or the terminal.

    Classical gain and phase margins, balanced disk margin with its simultaneous gain and phase variations.
    """
    def f(v, unit):
        return "inf" if v is None else f"{v:.3g}{unit}"

    lines = [f"sampled LQG, loop at a time: {'stable' if rob['stable'] else 'UNSTABLE'}, peak sensitivity "
             f"{f(rob['peak_sensitivity'], '')} (all loops)"]
    for a in rob["actuators"]:
        lead = " lead" if a.get("phase_margin_sense") == "lead" else ""
        lines.append(f"{a['input']:<16} gain margin {f(a['gain_margin_db'], ' dB'):>9}, phase margin "
                     f"{f(a['phase_margin_deg'], '°'):>6}{lead}; disk margin {f(a['disk_margin'], ''):>6}: "
                     f"±{f(a['disk_gain_margin_db'], ' dB')} with ±{f(a['disk_phase_margin_deg'], '°')}")
    if "multiloop" in rob:                 # controllers.diskmargin: every actuator at once
        ml = rob["multiloop"]
        lines.append(f"{'all at once':<16} disk margin {f(ml['disk_margin'], ''):>6}: "
                     f"±{f(ml['disk_gain_margin_db'], ' dB')} with ±{f(ml['disk_phase_margin_deg'], '°')} "
                     "at every actuator simultaneously")
    return "\n".join(lines)


def path_margins_text(along: dict) -> str:
    """The worst margins along a scheduled path (:func:`controllers.schedule.along_path`), a few lines.

    Per law (scheduled, fixed): whether every frozen pose holds (else where not), then per actuator the smallest
    gain margin, phase margin and disk margin over the stable poses, and the simultaneous disk margin and peak
    sensitivity of all loops, each with the path parameter σ where it is.
    """
    def at(e, fmt, unit=""):
        return "–" if e is None else f"{e['value']:{fmt}}{unit} (σ {e['sigma']:.3g})"

    first = next(iter(along.values()))["points"]
    sigma = ", ".join(f"{p['sigma']:.3g}" for p in first)
    lines = [f"sampled LQG frozen at each pose of the path, σ = {sigma}; worst over them:"]
    for name, a in along.items():
        w = a["worst"]
        verdict = (f"stable at every pose (largest spectral radius {at(w['spectral_radius'], '.4f')})" if w["stable"]
                   else "UNSTABLE at σ = " + ", ".join(f"{s:.3g}" for s in w["unstable_sigma"])
                   + "; over the stable poses")
        lines.append(f"{name} LQG: {verdict}; all at once disk margin {at(w['multiloop_disk_margin'], '.3g')}, "
                     f"peak sensitivity {at(w['peak_sensitivity'], '.3g')}")
        for act in w["actuators"]:
            lines.append(f"  {act['input']:<16} gain margin {at(act['gain_margin_db'], '.3g', ' dB')}, phase margin "
                         f"{at(act['phase_margin_deg'], '.3g', '°')}, disk margin {at(act['disk_margin'], '.3g')}")
    notes = {a.get("note") for a in along.values()} - {None}
    return "\n".join(lines + [f"note: {n}" for n in sorted(notes)])
