"""PNG figures of a paper-scenario run (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lab.paper.run import PaperRun  # noqa: E402
from smcpilot.model import CHANNELS, INPUT_UNITS, STATE_UNITS  # noqa: E402

LABELS = {
    "pid_smc": "PID-SMC (known χ)",
    "adaptive_pid_smc": "adaptive PID-SMC",
    "sign_smc": "sign SMC",
    "cascade_pid": "cascaded PID",
}
COLORS = {"pid_smc": "tab:blue", "adaptive_pid_smc": "tab:green", "sign_smc": "tab:red", "cascade_pid": "tab:gray"}
SYMBOLS = {"phi": "φ", "theta": "θ", "psi": "ψ", "z": "z"}
#: The two PID-SMC flavours nearly coincide in most panels: the known-bound one is drawn dashed on
#: top of a wider adaptive line, so that both stay visible, and the figures say so.
STYLES: dict[str, dict[str, Any]] = {
    "pid_smc": {"ls": (0, (4, 2)), "lw": 1.2, "zorder": 4},
    "adaptive_pid_smc": {"lw": 2.4, "alpha": 0.8, "zorder": 3},
    "sign_smc": {"lw": 1.2, "zorder": 2},
    "cascade_pid": {"lw": 1.2, "zorder": 2},
}
OVERLAP_NOTE = "PID-SMC (known χ) is dashed, on top of the adaptive PID-SMC: where only one shows, the two coincide."


def _style(name: str, **override: object) -> dict:
    return {**STYLES.get(name, {}), **override}


def _note_overlap(fig, names, extra: str = "") -> None:
    """Say under the figure that a dashed known-bound curve may hide in the adaptive one (and ``extra``)."""
    notes = [OVERLAP_NOTE] if "pid_smc" in names and "adaptive_pid_smc" in names else []
    if extra:
        notes.append(extra)
    if notes:
        fig.text(0.5, 0.005, " ".join(notes), ha="center", va="bottom", fontsize=8, color="0.3")


def _grid(title: str, nrows: int = 2, ncols: int = 2, height: float = 6.5):
    fig, axes = plt.subplots(nrows, ncols, figsize=(11, height), sharex=True, squeeze=False)
    fig.suptitle(title)
    return fig, axes


def _legend(ax, **kw) -> None:
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kw)


def _save(fig, out: Path, name: str) -> Path:
    fig.tight_layout(rect=(0, 0.025 if fig.texts else 0, 1, 1))
    path = out / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _mark_divergence(ax, tr) -> None:
    if tr.diverged and tr.diverged_at_s is not None:
        ax.axvline(tr.diverged_at_s, color=COLORS.get(tr.controller, "k"), ls=":", lw=1)


def write_figures(run: PaperRun, out_dir: str | Path) -> list[Path]:
    """Write every figure into ``out_dir`` (created if needed); return the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    trs = run.trajectories
    paths: list[Path] = []
    mode = "continuous RK4" if run.options.rate_hz is None else f"sampled at {run.options.rate_hz:g} Hz"
    sub = f"paper scenario, {mode}, σ from {run.options.sigma_source}"

    # 1. states vs references
    fig, axes = _grid(f"Attitude and altitude vs reference ({sub})")
    for i, c in enumerate(CHANNELS):
        ax = axes.flat[i]
        for name, tr in trs.items():
            ax.plot(tr.t_s, tr.x[:, 2 * i], color=COLORS[name], label=LABELS[name], **_style(name))
            _mark_divergence(ax, tr)
        first = next(iter(trs.values()))
        ax.plot(first.t_s, first.x_ref[:, i], "k--", lw=1, label="reference")
        ax.set_ylabel(f"{SYMBOLS[c]} [{STATE_UNITS[i]}]")
        ax.grid(alpha=0.3)
    _legend(axes[0, 0], fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    _note_overlap(fig, trs)
    paths.append(_save(fig, out, "states.png"))

    # 2. tracking errors (symlog so both the transient and the residual show)
    fig, axes = _grid(f"Tracking errors e = x − x_d ({sub})")
    for i, c in enumerate(CHANNELS):
        ax = axes.flat[i]
        for name, tr in trs.items():
            ax.plot(tr.t_s, tr.errors[:, i], color=COLORS[name], label=LABELS[name], **_style(name))
        ax.axhspan(-0.01, 0.01, color="k", alpha=0.07, label="±0.01" if i == 0 else None)
        ax.set_yscale("symlog", linthresh=1e-3)
        ax.set_ylabel(f"e_{SYMBOLS[c]} [{STATE_UNITS[i]}]")
        ax.grid(alpha=0.3)
    _legend(axes[0, 0], fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    _note_overlap(fig, trs)
    paths.append(_save(fig, out, "errors.png"))

    # 3. S and sigma of the PID-SMC flavours
    smc = {n: tr for n, tr in trs.items() if tr.s is not None}
    if smc:
        fig, axes = plt.subplots(4, 2, figsize=(11, 9), sharex=True)
        fig.suptitle(f"Sliding variable S and PID manifold σ ({sub})")
        for i, c in enumerate(CHANNELS):
            for name, tr in smc.items():
                assert tr.s is not None and tr.sigma is not None  # smc holds the sliding-mode laws only
                axes[i, 0].plot(tr.t_s, tr.s[:, i], color=COLORS[name], label=LABELS[name], **_style(name))
                axes[i, 1].plot(tr.t_s, tr.sigma[:, i], color=COLORS[name], label=LABELS[name], **_style(name))
            unit = "m/s" if c == "z" else "rad/s"  # c1 [1/s], c2, kp dimensionless, ki [1/s], kd [s]
            axes[i, 0].set_ylabel(f"S_{SYMBOLS[c]} [{unit}]")
            axes[i, 1].set_ylabel(f"σ_{SYMBOLS[c]} [{unit}]")
            for ax in axes[i]:
                ax.set_yscale("symlog", linthresh=1e-3)
                ax.grid(alpha=0.3)
        _legend(axes[0, 0], fontsize=8)
        axes[-1, 0].set_xlabel("t [s]")
        axes[-1, 1].set_xlabel("t [s]")
        _note_overlap(fig, smc)
        paths.append(_save(fig, out, "sliding.png"))

    # 4. inputs per channel
    fig, axes = _grid(f"Control inputs u ({sub})")
    for i, c in enumerate(CHANNELS):
        ax = axes.flat[i]
        for name, tr in trs.items():
            ax.plot(tr.t_s, tr.u[:, i], color=COLORS[name], label=LABELS[name], **_style(name, lw=STYLES.get(name, {}).get("lw", 1.2) * 0.7))
        ax.set_ylabel(f"u_{SYMBOLS[c]} [{INPUT_UNITS[i]}]")
        ax.grid(alpha=0.3)
        finite = np.concatenate([tr.u[:, i] for tr in trs.values() if tr.controller != "sign_smc"] or [np.zeros(1)])
        lim = np.nanpercentile(np.abs(finite), 99.5) if finite.size else 1.0
        if np.isfinite(lim) and lim > 0:
            ax.set_ylim(-1.3 * lim if np.nanmin(finite) < 0 else 0.0, 1.3 * lim)
    _legend(axes[0, 0], fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    _note_overlap(fig, trs, "Axes clipped at the 99.5th percentile of |u| (sign SMC left out of it): higher peaks are cut.")
    paths.append(_save(fig, out, "inputs.png"))

    # 5. chi_hat
    ad = trs.get("adaptive_pid_smc")
    known = trs.get("pid_smc")
    if ad is not None or known is not None:
        fig, axes = _grid(f"Switching gain χ̂ (adaptive) and χ (known bound) ({sub})")
        for i, c in enumerate(CHANNELS):
            ax = axes.flat[i]
            if ad is not None and ad.chi_hat is not None:
                ax.plot(ad.t_s, ad.chi_hat[:, i], color=COLORS["adaptive_pid_smc"], label="χ̂ (adaptive)")
            if known is not None and known.chi_hat is not None:
                ax.plot(known.t_s, known.chi_hat[:, i], "--", color=COLORS["pid_smc"], label="χ (known bound)")
            ax.set_ylabel(f"χ_{SYMBOLS[c]} [{'m/s²' if c == 'z' else 'rad/s²'}]")
            ax.grid(alpha=0.3)
        _legend(axes[0, 0], fontsize=8)
        for ax in axes[-1]:
            ax.set_xlabel("t [s]")
        paths.append(_save(fig, out, "chi_hat.png"))

    # 6. rotor speeds (signed square root of w^2, so unrealisable commands would show below zero)
    n = len(trs)
    fig, axes = plt.subplots(n, 1, figsize=(11, 2.2 * n + 0.8), sharex=True, squeeze=False)
    unrealisable = [LABELS[name] for name, tr in trs.items() if np.nanmin(tr.w_sq) < 0]
    note = ("ω² < 0 (not realisable) in: " + ", ".join(unrealisable)) if unrealisable else "every ω² ≥ 0: all commands realisable"
    fig.suptitle(f"Rotor speeds, signed √ω² ({note}) ({sub})")
    hover = float(np.sqrt(run.model.hover_omega_sq))
    for k, (name, tr) in enumerate(trs.items()):
        ax = axes[k, 0]
        w = np.sign(tr.w_sq) * np.sqrt(np.abs(tr.w_sq))
        for j in range(4):  # 3 and 4 dashed on top: in this scenario they shadow 1 and 2 closely
            ax.plot(tr.t_s, w[:, j], lw=1.6 if j < 2 else 0.9, ls="-" if j < 2 else (0, (3, 2)), label=f"ω{j + 1}")
        ax.axhline(hover, color="k", ls=":", lw=0.8, label="hover (level)")
        if np.nanmin(w) < 0:
            ax.axhline(0.0, color="tab:red", lw=0.8, label="below: ω² < 0")
        ax.set_ylabel(f"{LABELS[name]}\n[rad/s]", fontsize=8)
        ax.grid(alpha=0.3)
        lim = np.nanpercentile(np.abs(w), 99.5)
        if np.isfinite(lim) and lim > 0:
            ax.set_ylim(min(-0.05 * lim, np.nanmin(w)) if np.nanmin(w) < 0 else 0.0, 1.2 * lim)
    _legend(axes[0, 0], fontsize=7, ncol=6)
    axes[-1, 0].set_xlabel("t [s]")
    paths.append(_save(fig, out, "rotor_speeds.png"))

    # 7. chattering comparison: a zoom on u near the end, and total variation per controller
    fig, axes = plt.subplots(2, 4, figsize=(13, 6))
    t_end = max(float(tr.t_s[-1]) for tr in trs.values())
    z0 = min(10.0, max(0.0, t_end - 0.1))
    fig.suptitle(f"Chattering: u over 0.1 s at t = {z0:g} s (top) and total variation Σ|Δu| (bottom, log) ({sub})")
    for i, c in enumerate(CHANNELS):
        ax = axes[0, i]
        for name, tr in trs.items():
            sel = (tr.t_s >= z0) & (tr.t_s <= z0 + 0.1)
            if sel.any():
                ax.plot(tr.t_s[sel], tr.u[sel, i], color=COLORS[name], label=LABELS[name], **_style(name))
        ax.set_title(f"u_{SYMBOLS[c]} [{INPUT_UNITS[i]}]", fontsize=9)
        ax.grid(alpha=0.3)
        ax2 = axes[1, i]
        names = list(trs)
        tv = [float(np.sum(np.abs(np.diff(trs[nm].u[:, i])))) for nm in names]
        tv = [v if np.isfinite(v) and v > 0 else np.nan for v in tv]
        ax2.bar(range(len(names)), np.nan_to_num(tv, nan=0.0), color=[COLORS[nm] for nm in names])
        for k, _v in enumerate(tv):
            if trs[names[k]].diverged:
                ax2.annotate("diverged", (k, 0), xytext=(0, 3), textcoords="offset points", ha="center", fontsize=6, rotation=90)
        ax2.set_xticks(range(len(names)), [LABELS[nm].replace(" ", "\n", 1) for nm in names], fontsize=7)
        if any(np.isfinite(v) for v in tv):
            ax2.set_yscale("log")
        ax2.grid(alpha=0.3, axis="y")
    _legend(axes[0, 0], fontsize=7)
    _note_overlap(fig, trs)
    paths.append(_save(fig, out, "chattering.png"))
    return paths
