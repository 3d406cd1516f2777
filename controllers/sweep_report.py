"""What a finished sweep shows: its plain-text summary table and its figure (``flexlink sweep``, ``--plot``).

Apart from the running of a sweep (:mod:`controllers.sweep`) because both read only the results table, a
DataFrame from :func:`controllers.sweep.run_sweep` or one read back from its file, and matplotlib is imported
only when a figure is asked for.
"""

from __future__ import annotations

import math
import os

from controllers.sweep_worker import CLOSED_LOOP_METRICS, OPEN_LOOP_METRICS
from flexlink.errors import FlexlinkError

__all__ = ["PLOT_METRICS", "plot_sweep", "summary_table"]

PLOT_METRICS = ("overshoot_deg", "settling_time_s", "residual_vibration_rms_m", "peak_torque_nm",
                "max_tip_deflection_m", "final_error_deg", "final_angle_deg", "final_tip_deflection_m")


def summary_table(df) -> str:
    """A plain-text summary: cases, failures (grouped by message), and per metric count/mean/std/min/max."""
    from controllers.montecarlo import MULTIJOINT_METRICS

    metrics = [c for c in (*CLOSED_LOOP_METRICS, *OPEN_LOOP_METRICS, *MULTIJOINT_METRICS) if c in df.columns]
    metrics = list(dict.fromkeys(metrics))
    ok = df[~df["failed"]]
    lines = [f"{len(df)} cases ({df.attrs.get('kind', 'sweep')}): {len(ok)} ok, {int(df['failed'].sum())} failed"
             + (f"; {df.attrs['computed']} computed now, {df.attrs['resumed']} from the journal"
                if "computed" in df.attrs else "")]
    if df["failed"].any():
        lines.append("failures:")
        for msg, n in df.loc[df["failed"], "error"].value_counts().head(5).items():
            cases = df.loc[df["failed"] & (df["error"] == msg), "case"].tolist()
            shown = ", ".join(map(str, cases[:6])) + (", ..." if len(cases) > 6 else "")
            lines.append(f"  {n} x (case {shown}): {msg[:200]}")
    w = max(len(m) for m in metrics) if metrics else 10
    lines.append(f"  {'metric':<{w}} {'n':>5} {'mean':>11} {'std':>11} {'min':>11} {'max':>11}")
    for m in metrics:
        v = ok[m].dropna()
        if len(v) == 0:
            lines.append(f"  {m:<{w}} {0:>5}")
            continue
        std = v.std() if len(v) > 1 else 0.0
        lines.append(f"  {m:<{w}} {len(v):>5} {v.mean():>11.4g} {std:>11.4g} {v.min():>11.4g} {v.max():>11.4g}")
    return "\n".join(lines)


def plot_sweep(df, path: str | os.PathLike, title: str = "") -> None:
    """Plot a sweep's metrics: against the swept parameter for a grid, as histograms for Monte Carlo.

    A grid draws each metric against the first varying parameter, a line per value of the others (failed cases
    as red lines); a Monte Carlo sweep has no axis to draw against, so its metrics are shown as distributions.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(df.attrs.get("parameters") or [])
    metrics = [m for m in PLOT_METRICS if m in df.columns and df[m].notna().any()]
    if not metrics:
        raise FlexlinkError("--plot: no successful case to plot")
    ok = df[~df["failed"]]
    ncol = 2 if len(metrics) > 1 else 1
    nrow = math.ceil(len(metrics) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(6.0 * ncol, 3.0 * nrow + 0.6), squeeze=False)
    varying = [n for n in names if df[n].nunique() > 1]
    grid = df.attrs.get("kind") == "grid"
    for ax, m in zip(axes.flat, metrics, strict=False):
        if grid and varying:
            x = varying[0]
            others = varying[1:]
            groups = list(ok.groupby(others)) if others else [((), ok)]
            if len(groups) <= 8:
                for key, g in groups:
                    key = key if isinstance(key, tuple) else (key,)
                    label = ", ".join(f"{n}={v:.4g}" for n, v in zip(others, key, strict=True)) or None
                    g = g.sort_values(x)
                    ax.plot(g[x], g[m], marker="o", ms=3, lw=1.0, label=label)
                if others:
                    ax.legend(fontsize=6)
            else:
                sc = ax.scatter(ok[x], ok[m], c=ok[others[0]], s=10, cmap="viridis")
                fig.colorbar(sc, ax=ax, label=others[0])
            bad = df[df["failed"]]
            for xv in bad[x]:
                ax.axvline(xv, color="red", lw=0.6, alpha=0.4)
            ax.set_xlabel(x)
        else:
            v = ok[m].dropna()
            ax.hist(v, bins=max(5, min(40, int(math.sqrt(len(v))) + 1)), color="tab:blue", alpha=0.8)
            ax.set_xlabel(m)
            ax.set_ylabel("cases")
        ax.set_title(m, fontsize=9)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(metrics):]:
        ax.set_visible(False)
    n_bad = int(df["failed"].sum())
    fig.suptitle((title + ": " if title else "") + f"{len(df)} cases"
                 + (f", {n_bad} failed" + (" (red lines)" if grid and varying else "") if n_bad else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
