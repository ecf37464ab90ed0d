"""Fuzzing the ``facesim`` command (issue 14: bad input never hangs, crashes or passes silently).

* :mod:`tests.fuzz.bases` writes one valid file of every kind the CLI reads (the box model of
  ``tests/conftest.py``, 2-frame captures, controls, poses and rigs) and the valid invocation of
  every command on them;
* :mod:`tests.fuzz.mutations` turns a valid file (or option value, or collider spec) into a
  malformed or odd one, each operator saying whether its result may still be accepted;
* :mod:`tests.fuzz.cases` draws the cases of a seed: one input of one command mutated per case;
* :mod:`tests.fuzz.driver` runs them through ``facesim.cli.main`` in subprocesses (a timeout per
  case, a new process after a crash) and judges the outcome.

Reproduce a case from its id (printed on failure)::

    python -m tests.fuzz --seed 0 --only 'simulate.activations#0.3' --keep /tmp/fuzz
"""
