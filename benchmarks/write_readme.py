"""Run the benchmark scripts of this folder and write what they print to benchmarks/README.md.

    python benchmarks/write_readme.py                  # every benchmark, full size
    python benchmarks/write_readme.py --quick          # skip the thesis-size measurements where a script can
    python benchmarks/write_readme.py --only pbrl      # one benchmark (repeatable); the others' sections are kept

Each section records the command, when and at which commit it ran, the machine (CPU count and model,
load average when it started) and the script's output verbatim. A script prints rates and ratios
measured in one run; the machine may be shared, so compare ratios within a section, not rates across
sections or days.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from mop_core.storage.timings import cpu_model

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
README = HERE / "README.md"


@dataclass(frozen=True)
class Bench:
    name: str
    script: str
    threads: bool  # takes --threads
    quick_flag: str | None  # the script's small mode, if it has one


BENCHES = [
    Bench("collect", "bench_collect.py", threads=False, quick_flag="--quick-only"),
    Bench("pbrl", "bench_pbrl.py", threads=True, quick_flag="--quick-only"),
    Bench("reference", "bench_reference.py", threads=True, quick_flag="--quick-only"),
    Bench("distill", "bench_distill.py", threads=True, quick_flag=None),
    Bench("structure", "bench_structure.py", threads=True, quick_flag=None),
    Bench("shift", "bench_shift.py", threads=True, quick_flag=None),
    Bench("cluster", "bench_cluster.py", threads=False, quick_flag="--makespan-only"),
]
BY_NAME = {b.name: b for b in BENCHES}


def command(bench: Bench, threads: int, quick: bool) -> list[str]:
    args = ["python", f"benchmarks/{bench.script}"]
    if bench.threads:
        args += ["--threads", str(threads)]
    if quick and bench.quick_flag:
        args.append(bench.quick_flag)
    return args


def summary(bench: Bench) -> str:
    """The script's docstring (what it measures and prints), without its "Run: ..." line."""
    doc = ast.get_docstring(ast.parse((HERE / bench.script).read_text())) or ""
    return re.sub(r"\s*Run: ``[^`]*``\.?", "", doc).strip()


def git(*args: str) -> str:
    run = subprocess.run(["git", "--no-optional-locks", *args], cwd=ROOT, capture_output=True, text=True)
    return run.stdout.strip() if run.returncode == 0 else ""


def revision() -> str:
    commit = git("rev-parse", "--short=12", "HEAD") or "unknown"
    dirty = git("status", "--porcelain", "--untracked-files=no", "--", "mop_core", "benchmarks", "stages",
                "params.yaml", "profiles")
    return commit + (" with uncommitted changes to the code it measures" if dirty else "")


def machine() -> str:
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    return f"{os.cpu_count()} CPUs ({usable} usable), {cpu_model()}; load average (1, 5, 15 min) at start {load}"


def run_bench(bench: Bench, threads: int, quick: bool, timeout: float) -> str:
    """Run one benchmark; its README section (between markers, so --only can replace it alone)."""
    argv = command(bench, threads, quick)
    started_at = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    facts = machine()
    print(f"running {' '.join(argv)} ...", flush=True)
    start = time.perf_counter()
    env = os.environ | {"MOP_PROGRESS": "0"}
    try:
        run = subprocess.run([sys.executable, *argv[1:]], cwd=ROOT, env=env, capture_output=True, text=True,
                             timeout=timeout)
        output, status = run.stdout.rstrip(), f"exit status {run.returncode}"
        if run.returncode != 0:
            output += "\n--- stderr ---\n" + run.stderr.rstrip()
    except subprocess.TimeoutExpired as e:
        output = (e.stdout.decode() if isinstance(e.stdout, bytes) else e.stdout or "").rstrip()
        status = f"stopped after the {timeout:.0f} s limit"
    seconds = time.perf_counter() - start
    print(f"  {status}, {seconds:.0f} s", flush=True)
    mode = "full"
    if quick:
        mode = (f"quick (`{bench.quick_flag}`: thesis-size measurements skipped)" if bench.quick_flag
                else "full (the script has no small mode)")
    return "\n".join([
        f"<!-- bench:{bench.name} -->",
        f"## {bench.name}",
        "",
        summary(bench),
        "",
        f"- command: `{' '.join(argv)}`",
        f"- run: {started_at}, commit {revision()}, mode {mode}",
        f"- machine: {facts}",
        f"- took {seconds:.0f} s, {status}",
        "",
        "```",
        output,
        "```",
        f"<!-- /bench:{bench.name} -->",
    ])


def previous_sections() -> dict[str, str]:
    if not README.is_file():
        return {}
    text = README.read_text()
    return {m.group(1): m.group(0) for m in re.finditer(r"<!-- bench:(\w+) -->.*?<!-- /bench:\1 -->", text, re.S)}


GPU_FILES = ("gpu.txt", "tests.log", "rates.json", "plan.md", "short_plan.md", "short_timings.md", "repro.log")


def gpu_name(directory: Path) -> str:
    """A gpu section's name: ``gpu`` for benchmarks/gpu, ``gpu_<folder>`` for a dated run under it."""
    return "gpu" if directory.name == "gpu" else "gpu_" + re.sub(r"\W", "_", directory.name)


def gpu_section(directory: Path) -> str:
    """The GPU section from the files ``benchmarks/gpu_check.sh`` wrote (it runs on a lent GPU machine,
    not here): the card, the test suite's result on CUDA, the rates at the thesis sizes, the thesis
    profile's estimated cost, and the shortened thesis repro's stage times next to their estimate."""
    def read(name: str, tail: int | None = None) -> str:
        path = directory / name
        if not path.is_file():
            return f"({name}: not written)"
        lines = path.read_text().rstrip().splitlines()
        return "\n".join(lines[-tail:] if tail else lines)

    card, name, where = read("gpu.txt"), gpu_name(directory), directory.relative_to(ROOT).as_posix()
    rates = directory / "rates.json"
    profile = json.loads(rates.read_text()).get("profile", "thesis.yaml") if rates.is_file() else "thesis.yaml"
    title = "gpu" if name == "gpu" else f"gpu ({directory.name})"
    parts = [
        f"<!-- bench:{name} -->", f"## {title}", "",
        "`bash benchmarks/gpu_check.sh` on a lent GPU machine (the script says what each part does), its",
        f"files copied to `{where}/` and rendered here by `python benchmarks/write_readme.py --gpu {where}`.", "",
        "Card (nvidia-smi) and software:", "", "```", card, "```", ""]
    if (directory / "tests.log").is_file():
        parts += ["The tests with `MOP_TEST_DEVICE=cuda` (the learners, and where the run named them the tiny "
                  "profile's `dvc repro`, on CUDA), last lines:", "", "```", read("tests.log", 20), "```", ""]
    if '"tf32": true' in read("rates.json"):
        parts += ["**These rates ran with CUDA matmuls in TF32** (`bench_rates.py --tf32`): a measure of what TF32 "
                  "would buy; the study runs fp32.", ""]
    if (directory / "rates.log").is_file():  # what the captured updates buy: bench_rates' printed ratios
        ratios = [line for line in read("rates.log").splitlines() if line.endswith("x") or "x one" in line]
        parts += ["Measured in the same run, CUDA graphs against eager and rollouts over every core "
                  "(`rates.log`):", "", "```", *ratios, "```", ""]
    parts += [
        f"Rates at the sizes of profiles/{profile} (`benchmarks/bench_rates.py`; student rates are group "
        "updates/s for R runs):", "", "```json", read("rates.json"), "```", "",
        f"That profile's estimated cost (`python -m mop_core.plan profiles/{profile} --rates "
        f"{where}/rates.json`: the schedules times these rates; the script writes it as plan.md):", "",
        read("plan.md"), ""]
    if (directory / "short_timings.md").is_file():
        parts += [
            "The shortened thesis profile (every schedule at 0.1%, one level; `repro.log` beside these files), "
            "measured stage times:", "",
            read("short_timings.md"), "",
            "and what `mop_core.plan` estimates for that shortened profile from the rates "
            "above (per-run process "
            "start-up and file writes are not in the estimate; a stage missing above did not finish in the time "
            "limit):", "",
            read("short_plan.md"), ""]
    return "\n".join(parts + [f"<!-- /bench:{name} -->"])


def header(quick: bool, only: list[str] | None) -> str:
    lines = [
        "# Benchmarks",
        "",
        "Generated by `python benchmarks/write_readme.py`: do not edit by hand, rerun it. Each section is one",
        "benchmark script's output, verbatim, with the command, date, commit and machine it ran on. The",
        "scripts print rates and the ratios between implementations measured in one run. The machine may",
        "have been shared with other work while they ran (the load average at each start says how busy it",
        "was), and its speed varies from hour to hour: compare ratios within a section, not rates across",
        "sections or days.",
        "",
        "Regenerate: `python benchmarks/write_readme.py` (all, full size); `--quick` skips the thesis-size",
        "measurements of the scripts that have a small mode; `--only NAME` reruns one benchmark and keeps",
        f"the other sections. Names: {', '.join(b.name for b in BENCHES)}. The `reference` benchmark needs",
        "a checkout of the thesis's code at its pinned commit in `MOP_REFERENCE` (benchmarks/reference.py).",
    ]
    if quick:
        lines += ["", "**This file was written with `--quick`**: see each section's mode."]
    if only:
        lines += ["", f"Last written with `{' '.join(only)}`: the other sections are from earlier runs "
                      "(each gives its own date and commit)."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="use the scripts' small modes (--quick-only)")
    parser.add_argument("--only", action="append", choices=list(BY_NAME), metavar="NAME",
                        help=f"run only this benchmark (repeatable): {', '.join(BY_NAME)}")
    parser.add_argument("--threads", type=int, default=2,
                        help="torch threads of the scripts that take --threads (default 2, the stages' threads)")
    parser.add_argument("--timeout", type=float, default=1800, help="seconds allowed per script (default 1800)")
    parser.add_argument("--gpu", type=Path, help="render a gpu section from benchmarks/gpu_check.sh's files in "
                                                 "this folder (and run nothing else unless --only names it): "
                                                 "benchmarks/gpu is section gpu, benchmarks/gpu/<date> section "
                                                 "gpu_<date>, after it")
    args = parser.parse_args()
    started = time.perf_counter()
    sections = previous_sections() if args.only or args.gpu else {}
    for bench in BENCHES:
        if (args.only is None and args.gpu is None) or bench.name in (args.only or []):
            sections[bench.name] = run_bench(bench, args.threads, args.quick, args.timeout)
    if args.gpu is not None:
        sections[gpu_name(args.gpu.resolve())] = gpu_section(args.gpu.resolve())
    body = [sections[b.name] for b in BENCHES if b.name in sections] + [sections[name] for name in sorted(sections)
                                                                         if name.startswith("gpu")]
    last = [f"--only {name}" for name in args.only or []] + ([f"--gpu {args.gpu.as_posix()}"] if args.gpu else [])
    README.write_text(header(args.quick, last or None) + "\n\n" + "\n\n".join(body) + "\n")
    print(f"wrote {README.relative_to(ROOT)} in {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
