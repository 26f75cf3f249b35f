"""What a reader of the figures would flag, checked on the figures themselves (matplotlib objects
of a real flight's log and of a real paper run): labels inside the axes and not stacked, markers
not hidden, units on σ and χ̂, a dead zone that does not fill the axis, curves that coincide
said so, no "negative" where nothing is."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402
from matplotlib.patches import Polygon, Rectangle  # noqa: E402

from ground.logs import load_log  # noqa: E402
from ground.logs import plots as log_plots  # noqa: E402
from lab.run import fly  # noqa: E402
from smcpilot.scenario import Scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def step_yaw_log(tmp_path_factory: pytest.TempPathFactory):
    """The step-yaw example flown in-process: take-off at home, a step away and back home, a
    heading change across ±180°; its FC parameters include a σ dead zone."""
    sc = Scenario.from_toml(ROOT / "examples" / "scenarios" / "step-yaw.toml")
    res = fly(sc, tmp_path_factory.mktemp("fig"))
    assert res.status == "ok", res.message
    return load_log(res.tlog)


def _render(fig):  # type: ignore[no-untyped-def]
    fig.tight_layout()
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def test_track_labels_one_per_spot_inside_the_axes(step_yaw_log) -> None:
    fig = log_plots._figure_track(plt, step_yaw_log)
    try:
        renderer = _render(fig)
        (ax,) = fig.axes
        labels = [t for t in ax.texts if t.get_text().startswith("t=")]
        assert labels
        spots = [t.xy for t in labels]
        assert len(spots) == len(set(spots)), "one label per set-point spot, lines stacked inside it"
        box = ax.get_window_extent(renderer)
        for t in labels:
            bb = t.get_window_extent(renderer)
            assert box.x0 <= bb.x0 and bb.x1 <= box.x1 and box.y0 <= bb.y0 and bb.y1 <= box.y1, t.get_text()
        for a, b in zip(labels, labels[1:]):
            assert not a.get_window_extent(renderer).overlaps(b.get_window_extent(renderer)), (a.get_text(), b.get_text())
    finally:
        plt.close(fig)


def test_track_start_and_end_markers_are_drawn_over_the_set_points(step_yaw_log) -> None:
    fig = log_plots._figure_track(plt, step_yaw_log)
    try:
        (ax,) = fig.axes
        by_label = {line.get_label(): line for line in ax.lines}
        setpoint, start, end = by_label["set-point"], by_label["start"], by_label["end"]
        for marker in (start, end):
            assert marker.get_zorder() > setpoint.get_zorder()
            assert marker.get_markerfacecolor() == "none"  # hollow: the set-point shows through
    finally:
        plt.close(fig)


def test_controller_figure_has_units_and_a_dead_zone_that_does_not_fill_the_axis(step_yaw_log) -> None:
    bounds, dead_zone = log_plots._logged_adaptation(step_yaw_log)
    assert dead_zone, "the example flies with a σ dead zone"
    fig = log_plots._figure_controller(plt, step_yaw_log, bounds, dead_zone, "logged")
    try:
        _render(fig)
        ylabels = [ax.get_ylabel() for ax in fig.axes]
        sigma = [y for y in ylabels if y.startswith("σ_")]
        chi = [y for y in ylabels if y.startswith("χ̂_")]
        assert len(sigma) == len(chi) == 4
        assert all(y.endswith(("[rad/s]", "[m/s]")) for y in sigma), sigma
        assert all(y.endswith(("[rad/s²]", "[m/s²]")) for y in chi), chi
        for ax in fig.axes:
            if not ax.get_ylabel().startswith("σ_"):
                continue
            y0, y1 = ax.get_ylim()
            # No horizontal band over the σ axis (the armed shading is a vertical span, full height by design).
            for patch in ax.patches + ax.collections:
                if isinstance(patch, (Polygon, Rectangle)):
                    ext = patch.get_window_extent()
                    axe = ax.get_window_extent()
                    assert not (ext.width >= 0.99 * axe.width and ext.height < axe.height), "a horizontal band"
            assert any(abs(line.get_ydata()[0] - dead_zone) < 1e-12 for line in ax.lines if len(line.get_ydata()) == 2)
            assert y1 > y0
    finally:
        plt.close(fig)


@pytest.fixture(scope="module")
def paper_figures(tmp_path_factory: pytest.TempPathFactory):
    """Every paper figure of a short run of the two PID-SMC flavours, kept open for inspection."""
    from lab.paper import figures
    from lab.paper.run import PaperRunOptions, run_paper
    from lab.paper.scenario import PaperScenario

    run = run_paper(PaperRunOptions(controllers=("pid_smc", "adaptive_pid_smc", "sign_smc"), scenario=PaperScenario(duration_s=3.0)))
    kept: dict[str, object] = {}
    real_save = figures._save

    def keep(fig, out, name):  # type: ignore[no-untyped-def]
        kept[name] = fig
        fig.canvas.draw()
        path = out / name
        fig.savefig(path)
        return path

    figures._save = keep
    try:
        paths = figures.write_figures(run, tmp_path_factory.mktemp("paper"))
    finally:
        figures._save = real_save
    assert all(p.is_file() for p in paths)
    yield run, kept
    for fig in kept.values():
        plt.close(fig)  # type: ignore[arg-type]


def test_paper_figures_show_and_say_that_the_two_flavours_coincide(paper_figures) -> None:
    from lab.paper.figures import OVERLAP_NOTE

    _, figs = paper_figures
    for name in ("states.png", "errors.png", "sliding.png", "inputs.png"):
        fig = figs[name]
        assert any(OVERLAP_NOTE in t.get_text() for t in fig.texts), name  # type: ignore[attr-defined]
        ax = fig.axes[0]  # type: ignore[attr-defined]
        lines = {line.get_label(): line for line in ax.lines}
        known, adaptive = lines["PID-SMC (known χ)"], lines["adaptive PID-SMC"]
        assert known.get_zorder() > adaptive.get_zorder()  # drawn on top ...
        assert known.get_linestyle() != "-" and known.get_linewidth() < adaptive.get_linewidth()  # ... dashed, narrower


def test_rotor_speed_title_says_negative_only_where_there_is(paper_figures) -> None:
    run, figs = paper_figures
    title = figs["rotor_speeds.png"]._suptitle.get_text()  # type: ignore[attr-defined]
    any_negative = any(float(tr.w_sq.min()) < 0 for tr in run.trajectories.values())
    assert not any_negative  # the corrected scenario never asks for ω² < 0 ...
    assert "negative" not in title and "all commands realisable" in title  # ... and the title says so


def test_sliding_and_chi_axes_carry_units(paper_figures) -> None:
    _, figs = paper_figures
    ylabels = [ax.get_ylabel() for ax in figs["sliding.png"].axes + figs["chi_hat.png"].axes]  # type: ignore[attr-defined]
    assert ylabels and all(y.endswith("]") for y in ylabels), ylabels
