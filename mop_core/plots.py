"""Figures of the study as PNG files (matplotlib, no display needed)."""

from __future__ import annotations

import os
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from mop_core.storage.files import atomic_path  # noqa: E402

REFERENCE_DASHES = ["--", ":", "-.", (0, (5, 1, 1, 1, 1, 1))]  # band_curves' reference lines, in order


def _save(fig, path: str | os.PathLike) -> None:
    """Lay out and write a figure as PNG, atomically; close it."""
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _label(ax, xlabel: str, ylabel: str, title: str) -> None:
    """Axis labels, title, and a legend when the panel has labelled artists."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)


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
    _save(fig, path)


def learning_curves(path: str | os.PathLike, curves: Mapping[str, list[dict]], tasks: list[str], title: str) -> None:
    """One panel per task: ``return_mean_<task>`` against ``step`` for every named run's curve rows."""
    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 3.5), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        for name, rows in curves.items():
            key = f"return_mean_{task}"
            points = [(float(r["step"]), float(r[key])) for r in rows if key in r]
            if points:
                ax.plot(*zip(*points), marker="o", markersize=3, label=name)
        _label(ax, "gradient step", "episode return", task)
    fig.suptitle(title)
    _save(fig, path)


def sorted_activations(path: str | os.PathLike, mean_activations: Mapping[str, list[list[float]]], title: str) -> None:
    """Thesis Figure 6.3b: one panel per hidden layer; neurons sorted by the first task's mean
    activation (ascending), every other task's mean activation drawn in the same neuron order.
    An increasing trend in another task's curve means the tasks rank their neurons alike."""
    tasks = list(mean_activations)
    layers = len(mean_activations[tasks[0]])
    fig, axes = plt.subplots(1, layers, figsize=(5 * layers, 3.5), squeeze=False)
    for layer, ax in enumerate(axes[0]):
        reference = mean_activations[tasks[0]][layer]
        order = sorted(range(len(reference)), key=reference.__getitem__)
        for task in tasks:
            values = mean_activations[task][layer]
            ax.plot(range(len(order)), [values[k] for k in order], label=task, linewidth=1)
        ax.set_xlabel(f"neuron (sorted by {tasks[0]}'s mean activation)")
        ax.set_ylabel("mean activation")
        ax.set_title(f"hidden layer {layer + 1}")
        ax.legend(fontsize=8)
    fig.suptitle(title)
    _save(fig, path)


def metric_curves(path: str | os.PathLike, curves: Mapping[str, list[dict]], keys: list[str],
                  references: Mapping[str, list[float]] | None, ylabel: str, title: str) -> None:
    """One panel per curve column in ``keys`` (e.g. per-state tau of each layer) against ``step``;
    ``references[name][k]`` (e.g. the value at initialisation) is drawn as that run's dotted line."""
    fig, axes = plt.subplots(1, len(keys), figsize=(5 * len(keys), 3.5), squeeze=False)
    for k, (ax, key) in enumerate(zip(axes[0], keys)):
        for name, rows in curves.items():
            points = [(float(r["step"]), float(r[key])) for r in rows if key in r]
            if not points:
                continue
            line, = ax.plot(*zip(*points), marker="o", markersize=3, label=name)
            if references and name in references and k < len(references[name]):
                ax.axhline(references[name][k], color=line.get_color(), linestyle=":", linewidth=1)
        _label(ax, "gradient step", ylabel, key)
    fig.suptitle(title)
    _save(fig, path)


def band_curves(path: str | os.PathLike, panels: Mapping[str, Mapping[str, Mapping[str, list]]],
                references: Mapping[str, Mapping[str, float]], ylabel: str, title: str) -> None:
    """Learning curves as the thesis draws them (Figures 5.1, 5.3, 5.4): one panel per key of
    ``panels``; per label a line ``mean`` over ``step`` with a shaded ``ci_low``..``ci_high`` band
    where the series has one (several seeds); ``references[panel][label]`` as grey lines, one dash
    pattern each, named in the legend (text at the line overprints when two references are close)."""
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 3.8), squeeze=False)
    for ax, (panel, series) in zip(axes[0], panels.items()):
        for label, s in series.items():
            line, = ax.plot(s["step"], s["mean"], marker="o", markersize=3, label=label)
            if s.get("ci_low") is not None:
                ax.fill_between(s["step"], s["ci_low"], s["ci_high"], color=line.get_color(), alpha=0.2)
        for k, (label, value) in enumerate(references.get(panel, {}).items()):
            ax.axhline(value, linestyle=REFERENCE_DASHES[k % len(REFERENCE_DASHES)], linewidth=1.2,
                       color="dimgrey", label=label)
        _label(ax, "gradient step", ylabel, panel)
    fig.suptitle(title)
    _save(fig, path)


def _dodge_step(dodge: float | None, series: int, categorical: bool, log_x: bool) -> float:
    """interval_panels' horizontal distance between neighbouring series: ``dodge`` when given, else
    up to 0.2 categories (all series within 0.6) or 0.1 octaves (within 0.4); 0 on a linear numeric axis."""
    if dodge is not None:
        return dodge
    if series < 2 or not (categorical or log_x):
        return 0.0
    cap, spread = (0.2, 0.6) if categorical else (0.1, 0.4)
    return min(cap, spread / (series - 1))


def _dodged(x: float, offset: float, log_x: bool) -> float:
    """``x`` moved by ``offset``: multiplicatively (offset in octaves) on a log axis, else additively."""
    return x * 2.0 ** offset if log_x else x + offset


def interval_panels(path: str | os.PathLike, panels: Mapping[str, Mapping[str, list[tuple]]], xlabel: str,
                    ylabels: Mapping[str, str], title: str, log_x: bool = False, dodge: float | None = None) -> None:
    """One panel per entry of ``panels``; in each, one series of ``(x, mean, low, high)`` points
    drawn with its interval as error bars (``low``/``high`` None: no bar). Numeric x: each series'
    points joined by a line. Categorical x (strings): placed in order of first appearance, points
    with error bars and no connecting line (the categories have no order). Thesis Figures 6.4, 6.5.

    ``dodge`` shifts the k-th of n series by ``(k - (n - 1) / 2) * dodge`` horizontally so that
    intervals at one x stay apart: in category units for categorical x, in octaves (log2 units) on a
    log x axis, in data units on a linear numeric axis. None: an automatic dodge for categorical x
    and log x, none on a linear numeric axis (where x is a measured value, e.g. a KL)."""
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 3.6), squeeze=False)
    for ax, (name, series) in zip(axes[0], panels.items()):
        categories = list(dict.fromkeys(p[0] for points in series.values() for p in points if isinstance(p[0], str)))
        step = _dodge_step(dodge, len(series), bool(categories), log_x)
        for k, (label, points) in enumerate(series.items()):
            offset = (k - (len(series) - 1) / 2) * step
            xs = [_dodged(categories.index(p[0]) if isinstance(p[0], str) else p[0], offset,
                          log_x and not categories) for p in points]
            means = [p[1] for p in points]
            low = [p[1] - p[2] if p[2] is not None else 0.0 for p in points]
            high = [p[3] - p[1] if p[3] is not None else 0.0 for p in points]
            ax.errorbar(xs, means, yerr=[low, high], marker="o", capsize=3, label=label,
                        linestyle="none" if categories else "-")
        if categories:
            ax.set_xticks(range(len(categories)), categories, fontsize=8)
        if log_x and not categories:
            ax.set_xscale("log", base=2)
        _label(ax, xlabel, ylabels.get(name, ""), name)
    fig.suptitle(title)
    _save(fig, path)
