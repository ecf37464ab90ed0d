"""Fuzzing every reader and every command's inputs (issue 14: bad input never hangs, crashes or
passes silently).

Each case starts from a valid invocation of a command on tiny inputs (the box model of
``conftest.py``, 2-frame captures and controls, ``--max-steps 1``) and mutates one input: a model,
capture, controls, poses or rig file, a collider spec, an option value or an output path
(:mod:`tests.fuzz`). It runs in a driver subprocess with a timeout, and must end with a one-line
``facesim... error`` and a non-zero exit, or exit 0 where the mutation may be accepted -- never a
traceback, a timeout, a crash or exit 0 on garbage. The valid invocations themselves must succeed.

A failure prints its case id, what was mutated, the command line and how to run it again
(``python -m tests.fuzz --seed S --only ID --keep DIR``). Failures of a known class, waiting for a
fix elsewhere, are listed in :data:`KNOWN_FAILURES` by target and operator with a reproducer;
remove an entry when its fix lands.
"""

from __future__ import annotations

import pytest

from tests.fuzz.run import fuzz, known, report

#: ``(target glob, operator glob) -> (failure class, reproducer -- the file that has to change)``.
#: A class here is a bug waiting for its fix, not an accepted outcome: keep the list short and
#: remove an entry when the fix lands. Classes that hang ("timeout") are not run in CI (each would
#: cost its timeout); the slow test runs them.
KNOWN_FAILURES: dict[tuple[str, str], tuple[str, str]] = {}


def _check(tmp_path, seeds, scale, skip=None):
    cases, results, failures = fuzz(tmp_path, seeds=seeds, scale=scale, skip=skip)
    text = report(cases, results, failures, KNOWN_FAILURES)
    print(text)
    assert len(cases) > 0 and all(c["id"] in results for c in cases)
    baselines = [c for c in cases if c["op"] == "none"]
    assert baselines and all(results[c["id"]].rc == 0 for c in baselines), text
    new = [f for f in failures if not known(f.key, KNOWN_FAILURES)]
    assert not new, text


def test_fuzz_cli_inputs(tmp_path):
    """Seed 0: about 200 cases, every operator of every target at least once where the target has
    as many cases as operators (about a minute on 2 cores)."""
    hangs = {key: entry for key, entry in KNOWN_FAILURES.items() if entry[0] == "timeout"}
    _check(tmp_path, (0,), 1, skip=hangs)


@pytest.mark.slow
@pytest.mark.timeout(3 * 3600)
def test_fuzz_cli_inputs_many_seeds(tmp_path):
    """Seeds 1-5, five times the cases per target."""
    _check(tmp_path, (1, 2, 3, 4, 5), 5)
