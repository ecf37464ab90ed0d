"""One fuzz run: bases, cases, drivers, verdicts; and the failure report."""

from __future__ import annotations

import fnmatch
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from tests.fuzz.cases import make_cases
from tests.fuzz.driver import REPO, Result, Runner, judge, last_line


@dataclass(frozen=True)
class Failure:
    """A case whose outcome the rule does not allow: ``kind`` as :func:`~tests.fuzz.driver.judge`
    names it, ``key`` ``(target, op)`` as ``KNOWN_FAILURES`` lists it."""

    case: dict
    result: Result
    kind: str

    @property
    def key(self) -> tuple[str, str]:
        return self.case["target"], self.case["op"]

    def describe(self) -> str:
        c, r = self.case, self.result
        data = ""
        inputs = [p for p in Path(c["cwd"]).iterdir() if p.name not in ("stdout.txt", "stderr.txt")] \
            if Path(c["cwd"]).is_dir() else []
        for p in inputs:
            if p.is_file() and p.stat().st_size < 2000 and p.suffix in (".csv", ".trc", ".obj"):
                data += f"\n    {p.name}: {p.read_bytes()[:600]!r}"
        env = " ".join(f"{k}={v}" for k, v in c["env"].items())
        return (f"{c['id']} [{c['verdict']}] {self.kind}: {c['op']} -- {c['what']}\n"
                f"    {env + ' ' if env else ''}facesim {' '.join(_quote(a) for a in c['argv'])}\n"
                f"    exit {r.rc}, {r.seconds:.1f} s: {last_line(r)}{data}\n"
                f"    again: python -m tests.fuzz --seed {c['id'].split('#')[1].split('.')[0]} "
                f"--only '{c['id']}' --keep DIR")


def known(key: tuple[str, str], table: dict):
    """The entry of ``table`` (``{(target glob, op glob): (kind, note)}``) matching ``key``, or None."""
    for (target, op), entry in table.items():
        if fnmatch.fnmatchcase(key[0], target) and fnmatch.fnmatchcase(key[1], op):
            return entry
    return None


def _quote(a: str) -> str:
    return a if a and all(ch.isalnum() or ch in "/._-:=,+" for ch in a) else repr(a)


def build_bases(folder: Path) -> Path:
    """Write the bases in a subprocess (:mod:`tests.fuzz.bases`)."""
    env = dict(os.environ, PYTHONPATH=str(REPO), NUMBA_NUM_THREADS="1")
    p = subprocess.run([sys.executable, "-m", "tests.fuzz.bases", str(folder)], cwd=REPO, env=env,
                       capture_output=True, text=True, timeout=600)
    if p.returncode:
        raise RuntimeError(f"fuzz bases failed:\n{p.stderr[-3000:]}")
    return Path(folder)


def fuzz(work, seeds=(0,), scale: int = 1, only: str | None = None, workers: int = 2, skip=None):
    """Run the cases of ``seeds`` under ``work``: (cases, {id: Result}, [Failure]). ``skip``:
    a table like ``KNOWN_FAILURES`` of cases not to run."""
    work = Path(work)
    base = build_bases(work / "bases")
    cases = []
    for seed in seeds:
        made = make_cases(seed, base, work / f"seed{seed}", scale=scale, only=only)
        cases += [c for c in made if not (c["op"] == "none" and seed != seeds[0]) and
                  not (skip and known((c["target"], c["op"]), skip))]
    baselines = [c for c in cases if c["op"] == "none"]
    runner = Runner(work, workers)
    results = runner.run(baselines)          # first: the valid invocations, which also warm the JIT caches
    results.update(runner.run([c for c in cases if c["op"] != "none"]))
    failures = []
    for c in cases:
        kind = judge(c["verdict"], results[c["id"]])
        if kind:
            failures.append(Failure(c, results[c["id"]], kind))
    return cases, results, failures


def report(cases, results, failures, table=None) -> str:
    table = table or {}
    seconds = sum(r.seconds for r in results.values())
    lines = [f"{len(cases)} cases, {len(failures)} failures, {seconds:.0f} s in cases"]
    groups = {}
    for f in failures:
        groups.setdefault(f.key, []).append(f)
    for key, fs in sorted(groups.items()):
        mark = " (known)" if known(key, table) else ""
        lines.append(f"\n== {key[0]} / {key[1]}: {len(fs)} x {', '.join(sorted({f.kind for f in fs}))}{mark}")
        lines.append(fs[0].describe())
    return "\n".join(lines)
