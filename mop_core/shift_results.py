"""What the state_shift stage derives from its student table (mop_core.shift_study.student_table):
what each row is (:func:`describe`), Hypothesis 1 on the measured axis (:func:`shift_correlations`)
and the figures (Figure 5.8's return against width; return against the measured shift)."""

from __future__ import annotations

from pathlib import Path

from scipy.stats import spearmanr

from mop_core.plots import interval_panels
from mop_core.runs import correction_parts, shift_data, size_percent
from mop_core.study import OFFLINE_DATA


def describe(label: str, width: int) -> dict:
    """What a table row is: its data (offline, a composed dataset), width, dataset share and state-shift
    correction (none, reweight, dagger)."""
    correction = (correction_parts(label) or ("none",))[0]
    if label.startswith(f"{OFFLINE_DATA}_w"):
        return {"data": OFFLINE_DATA, "width": int(label[len(OFFLINE_DATA) + 2:]), "percent": 100,
                "correction": correction}
    parts = shift_data(label)
    if parts:
        return {"data": parts[0], "width": parts[1], "percent": 100, "correction": correction}
    return {"data": OFFLINE_DATA, "width": width, "percent": size_percent(label), "correction": correction}


def plain(info: dict) -> bool:
    """A row of students without a state-shift correction at the whole dataset (the figures' points)."""
    return info["percent"] == 100 and info["correction"] == "none"


def shift_points(metrics: dict, tasks) -> dict[int, dict[str, list[tuple[float, float]]]]:
    """Per width and task: (measured KL(teacher || data), the students' mean student/teacher return) of
    every dataset (offline and composed), at full size."""
    points: dict[int, dict[str, list[tuple[float, float]]]] = {}
    for label, info in metrics["groups"].items():
        if not plain(info):
            continue
        for task in tasks:
            data = info["data"] if info["data"] != OFFLINE_DATA else metrics["pairing_levels"][task]
            measured = metrics["shift"].get(task, {}).get(data)
            if measured:
                points.setdefault(info["width"], {}).setdefault(task, []).append(
                    (measured["kl"], metrics["students"][label][task]["to_teacher"]["mean"]))
    return points


def shift_correlations(metrics: dict, tasks) -> dict[str, dict[str, dict]]:
    """Hypothesis 1 on a measured axis: per width and task, Spearman's rank correlation between the
    measured shift and the student/teacher return over the datasets (negative: more shift, less
    return). Per task: the tasks' KL scales differ (a teacher holding a pose is a near-degenerate
    set), so pooling them would rank tasks, not shifts."""
    out: dict[str, dict[str, dict]] = {}
    for width, by_task in sorted(shift_points(metrics, tasks).items()):
        for task, points in by_task.items():
            if len(points) >= 3:
                rho, p = spearmanr([q[0] for q in points], [q[1] for q in points])
                out.setdefault(str(width), {})[task] = {"spearman": float(rho), "p_value": float(p),
                                                        "points": len(points)}
    return out


def write_figures(metrics: dict, tasks, figures: Path) -> None:
    """Figure 5.8 (return against width, one line per dataset, 95% CI over seeds) and the return
    against the measured shift (one line per width)."""
    groups, table = metrics["groups"], metrics["students"]
    capacity: dict = {}
    shift: dict = {}
    for label, info in groups.items():
        if not plain(info):
            continue
        for task in tasks:
            r = table[label][task]["return"]
            capacity.setdefault(task, {}).setdefault(info["data"], []).append(
                (info["width"], r["mean"], r["ci_low"], r["ci_high"]))
            measured = metrics["shift"].get(task, {}).get(info["data"] if info["data"] != OFFLINE_DATA
                                                          else metrics["pairing_levels"][task])
            if measured:
                ratio = table[label][task]["to_teacher"]
                shift.setdefault(task, {}).setdefault(f"width {info['width']}", []).append(
                    (measured["kl"], ratio["mean"], ratio["ci_low"], ratio["ci_high"]))
    for panels in (capacity, shift):
        for series in panels.values():
            for points in series.values():
                points.sort(key=lambda p: p[0])
    if capacity:
        interval_panels(figures / "capacity.png", capacity, "hidden width",
                        {t: "return (95% CI over seeds)" for t in tasks},
                        "Students by width and dataset (thesis Figure 5.8)", log_x=True)
    if shift:
        interval_panels(figures / "shift_returns.png", shift, "KL(teacher states || dataset states), nats (kNN)",
                        {t: "student / teacher return" for t in tasks},
                        "Student return against the measured state shift (Hypothesis 1)")
