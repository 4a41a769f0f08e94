"""The pipeline as DVC sees it: each stage entry, the entries it reads from, and which must run."""

from __future__ import annotations

import json
import subprocess
from dataclasses import dataclass
from pathlib import Path

# entries whose output does not change with the params they check: the params stage writes the same line
# (data/params_checked.txt) for every valid params.yaml and fails on any other
CHECKS = ("params",)


@dataclass(frozen=True)
class StageGraph:
    """``upstream[entry]``: the entries whose outputs ``entry`` depends on (DVC's own edges)."""

    upstream: dict[str, tuple[str, ...]]

    def order(self) -> list[str]:
        """Every entry after all of its upstream entries (dvc.yaml's order among ready ones)."""
        done: list[str] = []
        placed: set[str] = set()
        pending = list(self.upstream)
        while pending:
            ready = [name for name in pending if set(self.upstream[name]) <= placed]
            if not ready:
                raise ValueError(f"dvc.yaml: a cycle among {sorted(pending)}")
            done += ready
            placed |= set(ready)
            pending = [name for name in pending if name not in placed]
        return done

    def downstream_closure(self, entries: set[str]) -> set[str]:
        """``entries`` and every entry that reads, directly or not, from one of them, except through a
        CHECKS entry (its output is the same for every valid params file, so DVC skips its readers)."""
        closed = set(entries)
        for name in self.order():
            if set(self.upstream[name]) & (closed - set(CHECKS)):
                closed.add(name)
        return closed

    def upstream_closure(self, entries: set[str]) -> set[str]:
        """``entries`` and every entry they read from, directly or not: what ``dvc repro ENTRY`` may run."""
        closed, pending = set(), list(entries)
        while pending:
            name = pending.pop()
            if name not in closed:
                closed.add(name)
                pending += self.upstream[name]
        return closed

    def resolve(self, targets: tuple[str, ...]) -> set[str]:
        """The entries ``targets`` name as ``dvc repro`` reads them: an entry (``distill@mse-medium``) or a
        stage, meaning all of its matrix entries (``distill``). An unknown name raises ValueError naming it."""
        found: set[str] = set()
        for target in targets:
            named = {e for e in self.upstream if e == target or e.split("@", 1)[0] == target}
            if not named:
                stages = sorted({e.split("@", 1)[0] for e in self.upstream})
                raise ValueError(f"target {target!r}: no such stage or entry in dvc.yaml (stages: {', '.join(stages)})")
            found |= named
        return found


def stage_graph(root: Path) -> StageGraph:
    """The DAG of ``root``'s dvc.yaml, with matrix and foreach entries expanded (``stage@entry``)."""
    from dvc.repo import Repo

    with Repo(str(root)) as repo:
        graph = repo.index.graph  # an edge runs from a stage to each stage it depends on
        return StageGraph({stage.name: tuple(sorted(up.name for up in graph.successors(stage)))
                           for stage in graph.nodes})


def stale_entries(root: Path, graph: StageGraph, targets: tuple[str, ...] = ()) -> list[str]:
    """The entries ``dvc repro [TARGETS]`` would run: those ``dvc status`` names and everything downstream of
    them; with ``targets``, only those the targets read from (the targets included)."""
    result = subprocess.run(["dvc", "status", "--json"], cwd=root, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"dvc status failed in {root}:\n{result.stderr.strip()}")
    changed = set(json.loads(result.stdout or "{}")) & set(graph.upstream)
    closure = graph.downstream_closure(changed)
    if targets:
        closure &= graph.upstream_closure(graph.resolve(targets))
    return [name for name in graph.order() if name in closure]
