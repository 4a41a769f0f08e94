"""mop_core/plots.py: every figure is written as a PNG (atomically), and a learning-curve TSV reads back
as it was written or fails naming the file."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import pytest

from mop_core import plots
from mop_core.config import InputFileError
from mop_core.plots import (
    band_curves,
    interval_panels,
    learning_curves,
    metric_curves,
    returns_bar_chart,
    sorted_activations,
)
from mop_core.report.common_structure import comparison
from mop_core.report.results import Run, StudyResults
from mop_core.storage.artifacts import read_curve, write_curve

PNG = b"\x89PNG\r\n\x1a\n"
CURVES = {"teacher": [{"step": "10", "return_mean_stand": "1.5", "tau_layer1": "0.2"},
                      {"step": "20", "return_mean_stand": "4.0", "tau_layer1": "0.5"}],
          "student": [{"step": 10, "return_mean_walk": 2.0, "tau_layer1": 0.1}]}


def _is_png(path) -> bool:
    return path.read_bytes()[:8] == PNG and not [p for p in path.parent.iterdir() if ".tmp-" in p.name]


def test_returns_bar_chart(tmp_path):
    row = {"mean": 3.0, "ci_low": 2.0, "ci_high": 4.5, "n": 3, "ci_unit": "seed"}
    summary = {"stand": {"teacher_medium": row, "student_mse_medium": row | {"ci_low": None, "ci_high": None}},
               "walk": {"teacher_medium": row}}
    path = tmp_path / "figures" / "returns.png"  # missing folders are made
    returns_bar_chart(path, summary, "returns")
    assert _is_png(path)


def test_learning_curves_and_metric_curves(tmp_path):
    learning_curves(tmp_path / "learning.png", CURVES, ["stand", "walk", "run"], "curves")  # run: an empty panel
    assert _is_png(tmp_path / "learning.png")
    metric_curves(tmp_path / "metric.png", CURVES, ["tau_layer1", "tau_layer2"], {"teacher": [0.0], "other": [1.0]},
                  "tau", "per-state tau")
    assert _is_png(tmp_path / "metric.png")
    metric_curves(tmp_path / "metric_plain.png", CURVES, ["tau_layer1"], None, "tau", "no references")
    assert _is_png(tmp_path / "metric_plain.png")


def test_sorted_activations(tmp_path):
    activations = {"stand": [[0.3, 0.1, 0.2], [1.0, 0.0]], "walk": [[0.2, 0.2, 0.1], [0.5, 0.5]]}
    sorted_activations(tmp_path / "activations.png", activations, "activations")
    assert _is_png(tmp_path / "activations.png")


def test_band_curves(tmp_path):
    panels = {"stand": {"mse": {"step": [1, 2, 3], "mean": [1.0, 2.0, 3.0], "ci_low": [0.5, 1.5, 2.5],
                                "ci_high": [1.5, 2.5, 3.5]},
                        "kl": {"step": [1, 2, 3], "mean": [0.0, 1.0, 1.0]}},  # one seed: no band
              "walk": {"kl": {"step": [1, 2], "mean": [2.0, 2.0], "ci_low": None}}}
    band_curves(tmp_path / "band.png", panels, {"stand": {"teacher": 3.2}}, "return", "students")
    assert _is_png(tmp_path / "band.png")


def test_a_figure_replaces_an_older_file(tmp_path):
    path = tmp_path / "returns.png"
    path.write_bytes(b"old")
    learning_curves(path, CURVES, ["stand"], "curves")
    assert _is_png(path)


def test_read_curve_reads_back_what_write_curve_wrote(tmp_path):
    rows = [{"step": 10, "return_mean": 1.5, "loss": -0.25}, {"step": 20, "return_mean": 3.0, "loss": 1e-05}]
    write_curve(tmp_path / "run.tsv", rows)
    assert read_curve(tmp_path / "run.tsv") == [{"step": "10", "return_mean": "1.5", "loss": "-0.25"},
                                                {"step": "20", "return_mean": "3.0", "loss": "1e-05"}]
    (tmp_path / "header_only.tsv").write_text("step\tx\n")  # no evaluation yet
    assert read_curve(tmp_path / "header_only.tsv") == []


def test_read_curve_names_a_missing_empty_foreign_or_truncated_file(tmp_path):
    missing = tmp_path / "missing.tsv"
    with pytest.raises(InputFileError) as err:
        read_curve(missing)
    assert str(err.value) == f"{missing}: learning curve not found"
    empty = tmp_path / "empty.tsv"
    empty.write_text("")
    with pytest.raises(InputFileError, match=r"empty\.tsv: not a learning-curve TSV \(empty or garbled\)"):
        read_curve(empty)
    binary = tmp_path / "binary.tsv"
    binary.write_bytes(b"\x80\x81\xff\n")
    with pytest.raises(InputFileError, match=r"binary\.tsv: not a learning-curve TSV \(empty or garbled\)"):
        read_curve(binary)
    no_step = tmp_path / "no_step.tsv"
    no_step.write_text("epoch\treturn\n1\t2\n")
    with pytest.raises(InputFileError) as err:
        read_curve(no_step)
    assert str(err.value) == f"{no_step}: not a learning-curve TSV (no 'step' column in the header 'epoch\\treturn')"
    truncated = tmp_path / "truncated.tsv"
    write_curve(truncated, [{"step": 10, "return_mean": 1.5, "loss": 0.5}, {"step": 20, "return_mean": 3.0,
                                                                           "loss": 0.25}])
    text = truncated.read_text()
    truncated.write_text(text[:text.rindex("\t")])  # the write stopped inside the last row
    with pytest.raises(InputFileError) as err:
        read_curve(truncated)
    assert str(err.value) == f"{truncated}: line 3 has 2 columns, the header 3 (truncated?)"


@pytest.fixture
def drawn(monkeypatch):
    """The figures the plot functions draw, kept open instead of written (to look at their artists)."""
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig))
    yield figures
    for fig in figures:
        plt.close(fig)


def test_band_curves_name_the_references_in_the_legend_not_at_the_line(drawn):
    panels = {"stand": {"mse": {"step": [1, 2], "mean": [1.0, 2.0]}}}
    band_curves("unused.png", panels, {"stand": {"medium deterministic teacher": 3.0,
                                                 "medium gaussian teacher": 3.01}}, "return", "students")
    ax = drawn[0].axes[0]
    assert not ax.texts  # two close references' text labels overprinted each other
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["mse", "medium deterministic teacher",
                                                                   "medium gaussian teacher"]
    references = [line for line in ax.get_lines() if line.get_label().endswith("teacher")]
    assert len({line.get_linestyle() for line in references}) == 2  # told apart by their dash pattern


def _x_of(ax, label: str) -> list[float]:
    """The x values of the errorbar series ``label`` (its marker line)."""
    container = next(c for c in ax.containers if c.get_label() == label)
    return list(container.lines[0].get_xdata())


def test_categorical_interval_panels_draw_points_without_connecting_lines_dodged_per_series(drawn):
    series = {"teachers": [("MOP", 400.0, 300.0, 500.0), ("DS", 500.0, 420.0, 580.0)],
              "students": [("MOP", 350.0, 210.0, 500.0), ("DS", 490.0, None, None), ("OQS own", 620.0, 580.0, 660.0)]}
    interval_panels("unused.png", {"return": series}, "approach", {"return": "return"}, "categories")
    ax = drawn[0].axes[0]
    assert all(line.get_linestyle() == "None" for line in ax.get_lines() if len(line.get_xdata()) > 1)
    teachers, students = _x_of(ax, "teachers"), _x_of(ax, "students")
    assert teachers[0] < 0 < students[0] and teachers[1] < 1 < students[1]  # MOP at 0, DS at 1, apart
    assert [round(x) for x in students] == [0, 1, 2]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["MOP", "DS", "OQS own"]


def test_log_x_interval_panels_dodge_each_series_and_keep_their_lines(drawn):
    series = {data: [(16, 200.0 + k, 100.0, 300.0), (256, 500.0, 400.0, 600.0)]
              for k, data in enumerate(["offline", "online", "noise", "random90", "random99"])}
    interval_panels("unused.png", {"stand": series}, "hidden width", {}, "capacity", log_x=True)
    ax = drawn[0].axes[0]
    at_16 = [_x_of(ax, label)[0] for label in series]
    assert at_16 == sorted(at_16) and len(set(at_16)) == 5  # one x per dataset, in series order
    assert 16 / 2 ** 0.25 <= at_16[0] and at_16[-1] <= 16 * 2 ** 0.25 and at_16[2] == pytest.approx(16)
    assert ax.get_xscale() == "log"
    assert all(c.lines[0].get_linestyle() == "-" for c in ax.containers)  # widths are ordered: joined


def test_linear_numeric_interval_panels_keep_measured_x(drawn):
    series = {"width 16": [(0.5, 1.0, None, None), (1.5, 0.8, 0.7, 0.9)], "width 64": [(0.5, 0.9, 0.8, 1.0)]}
    interval_panels("unused.png", {"stand": series}, "KL", {}, "shift")
    ax = drawn[0].axes[0]
    assert _x_of(ax, "width 16") == [0.5, 1.5] and _x_of(ax, "width 64") == [0.5]
    interval_panels("unused.png", {"stand": series}, "KL", {}, "shift", dodge=0.1)  # asked for
    assert _x_of(drawn[1].axes[0], "width 16") == pytest.approx([0.45, 1.45])


def test_the_width_figure_says_its_tau_is_on_probe_states(drawn):
    runs = [Run({"loss": "mse", "variant": "w16", "pairing": "medium"}, seed, {"per_state_tau": {
        "probe_source": "offline", "final": {"per_state_tau_a_layer1": 0.4 + 0.01 * seed}}}, []) for seed in range(3)]
    results = StudyResults(tasks=["stand"], levels=["medium"], settings={})
    comparison(results, [(16, "mse-w16", runs), (64, "mse-w64", runs)], "hidden width", Path("width.png"),
               "width.png", "hidden width (every layer)", "MSE students by width", log_x=True)
    ax = next(ax for ax in drawn[0].axes if "tau" in ax.get_title())
    assert ax.get_title() == "per-state tau on probe states (offline dataset states)"
    assert "on probe states" in ax.get_ylabel()
