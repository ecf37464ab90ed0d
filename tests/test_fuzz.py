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
KNOWN_FAILURES: dict[tuple[str, str], tuple[str, str]] = {
    # facesim/_csv.py read_table/read_text: a named pipe nobody writes to blocks open() forever
    ("simulate.activations", "file:fifo"): ("timeout", "mkfifo a.csv; facesim simulate --model M --activations a.csv -o out"),
    ("simulate.jaw.*", "file:fifo"): ("timeout", "mkfifo j.csv; facesim simulate ... --jaw j.csv"),
    ("simulate.collider.path", "file:fifo"): ("timeout", "mkfifo p.csv; --collider sphere:radius=5,path=p.csv"),
    ("solve-mocap.markers.csv", "file:fifo"): ("timeout", "mkfifo m.csv; facesim solve-mocap --markers m.csv ..."),
    # facesim/jaw/rigfile.py rig_kind: np.load of a named pipe blocks (no is_file check before it)
    ("*.rig", "file:fifo"): ("timeout", "mkfifo r.npz; facesim jaw eval --rig r.npz --poses P.npz"),
    # facesim/mocap/io.py read_c3d: ezc3d hangs or segfaults on a C3D cut inside its parameter section
    ("solve-mocap.markers.c3d", "c3d:truncate"): ("timeout", "head -c 739 m.c3d > cut.c3d (hangs), head -c 518 "
                                                  "(SIGSEGV); facesim solve-mocap --markers cut.c3d ..."),
    # facesim/cli.py: solve-mocap options taken without a range check
    ("solve-mocap.options", "option:--loss-scale=*"): ("exit 0 on garbage", "--loss-scale inf (or nan, -1, 0)"),
    ("solve-mocap.options", "option:--noise=*"): ("not one line", "--noise inf: RuntimeWarnings, then 'controls.jaw: "
                                                  "expected 3 finite ...'"),
    ("solve-mocap.options", "option:--*frames="): ("exit 0 on garbage", "--frames '' and --bind-frames '' are ignored"),
    ("solve-mocap.options", "option:--scheduler=*"): ("traceback", "--scheduler not-an-address: ValueError: missing "
                                                      "port number"),
    ("simulate.output", "out:empty"): ("exit 0 on garbage", "facesim simulate ... -o '': writes the run into the "
                                       "current folder"),
    # facesim/jaw/cli.py: seeds and noise of generate / fit-model
    ("jaw *.options", "option:--session=-1"): ("traceback", "facesim jaw generate --extremes -o p.npz --session -1: "
                                               "ValueError: expected non-negative integer (also fit-model)"),
    ("jaw *.options", "option:--noise=1e*"): ("exit 0 on garbage", "facesim jaw generate --extremes -o p.npz --noise "
                                              "1e30 writes poses 1e30 mm away; fit-model --noise 1e3 prints "
                                              "LinAlgWarning (posselt.py:568)"),
    ("jaw generate.options", "option:--extremes=None"): ("exit 0 on garbage", "facesim jaw generate -o p.npz "
                                                         "--noise 1e30"),
    # facesim/jaw/cli.py read_poses: finite but absurd values
    ("jaw *.poses", "npz:value:*1e+30"): ("exit 0 on garbage", "poses file with reference_point[2] = -1e30: "
                                          "jaw eval / jaw fit accept it"),
    # the rig loaders (facesim/jaw/posselt.py, classic.py, nlpca.py): no dtype or content check of the arrays
    ("*.rig", "npz:dtype:*"): ("exit 0 on garbage", "rig with frame_axes stored as strings (or curves as bool, "
                               "centres complex: ComplexWarning) loads: jaw eval/pose succeed"),
    ("*.rig", "npz:value:*1e+30"): ("exit 0 on garbage", "3dof rig with origin[2] = 1e30: jaw eval succeeds"),
    ("*.rig", "rig:curves_collapsed"): ("exit 0 on garbage", "posselt rig with curves all zero: jaw pose succeeds"),
    ("*.rig", "npz:meta:value_*"): ("traceback", "posselt rig with meta.curves = NaN: jaw pose: TypeError: 'float' "
                                    "object is not iterable"),
    # facesim/model.py content check: coordinates not bounded (and facesim/contact/sdf.py MeshSDF.from_mesh
    # warns 'invalid value encountered in cast' on a collider vertex at -1e30 before its error)
    ("model *", "npz:value:*1e+30"): ("exit 0 on garbage", "model with jaw_condyle_right[1] = -1e30: model info "
                                      "succeeds"),
    ("model *", "model:huge_model"): ("exit 0 on garbage", "model with X * 1e12: model export succeeds"),
    ("*.model", "npz:value:*1e+30"): ("not one line", "model with collider0_vertices[6, 1] = -1e30: simulate prints "
                                      "a RuntimeWarning before 'grid values: expected finite ...'"),
    # facesim/contact/sdf.py KinematicPath.from_csv: unknown columns ignored
    ("simulate.collider.path", "csv:add_column:unknown"): ("exit 0 on garbage", "path CSV 'frame,x,y,z,extra' "
                                                           "accepted"),
}


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
