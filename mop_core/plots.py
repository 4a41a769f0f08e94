"""Figures of the study as PNG files (matplotlib, no display needed)."""

from __future__ import annotations

import os
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from mop_core.data.hdf5 import atomic_path  # noqa: E402


def returns_bar_chart(path: str | os.PathLike, summary: Mapping[str, Mapping[str, Mapping]], title: str) -> None:
    """One panel per task, one bar per policy group: mean return with its 95% CI as an error bar.

    ``summary[task][group]`` holds ``mean``, ``ci_low``, ``ci_high``, ``n`` and ``ci_unit``.
    """
    tasks = list(summary)
    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 0.45 * max(len(g) for g in summary.values())
                                                      + 1.5), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        groups = list(summary[task])
        means = [summary[task][g]["mean"] for g in groups]
        low = [m - (summary[task][g]["ci_low"] if summary[task][g]["ci_low"] is not None else m)
               for g, m in zip(groups, means)]
        high = [(summary[task][g]["ci_high"] if summary[task][g]["ci_high"] is not None else m) - m
                for g, m in zip(groups, means)]
        ax.barh(range(len(groups)), means, xerr=[low, high], color="tab:blue", alpha=0.8, capsize=3)
        ax.set_yticks(range(len(groups)), [f"{g} (n={summary[task][g]['n']} {summary[task][g]['ci_unit']}s)"
                                           for g in groups], fontsize=8)
        ax.invert_yaxis()
        ax.set_xlabel("episode return (mean, 95% CI)")
        ax.set_title(task)
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def learning_curves(path: str | os.PathLike, curves: Mapping[str, list[dict]], tasks: list[str], title: str) -> None:
    """One panel per task: ``return_mean_<task>`` against ``step`` for every named run's curve rows."""
    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 3.5), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        for name, rows in curves.items():
            key = f"return_mean_{task}"
            points = [(float(r["step"]), float(r[key])) for r in rows if key in r]
            if points:
                ax.plot(*zip(*points), marker="o", markersize=3, label=name)
        ax.set_xlabel("gradient step")
        ax.set_ylabel("episode return")
        ax.set_title(task)
        ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def read_curve(path: str | os.PathLike) -> list[dict[str, str]]:
    """The rows of a learning-curve TSV (:func:`mop_core.artifacts.write_curve`), values as strings."""
    with open(path) as f:
        header, *lines = f.read().splitlines()
    keys = header.split("\t")
    return [dict(zip(keys, line.split("\t"))) for line in lines]
