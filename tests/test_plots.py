"""mop_core/plots.py: every figure is written as a PNG (atomically), and a learning-curve TSV reads back
as it was written or fails naming the file."""

from __future__ import annotations

import pytest

from mop_core.artifacts import read_curve, write_curve
from mop_core.config import InputFileError
from mop_core.plots import (
    band_curves,
    learning_curves,
    metric_curves,
    returns_bar_chart,
    sorted_activations,
)

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
