"""The fuzz cases: every command's valid invocation on the bases (:mod:`tests.fuzz.bases`), with
one input mutated per case.

A :class:`Target` is one input of one command -- a file (``simulate.activations``), an option
(``solve-mocap.options``), a collider spec, an output path -- with the operators that mutate it.
:func:`make_cases` draws ``n`` cases per target for a seed: case ``i`` of a target uses the
operators in turn (so a few cases cover them all) with ``random.Random(f"{seed}/{target}/{i}")``
choosing where and how, writes the mutated input into its own folder and returns what the driver
runs. The case id ``TARGET#SEED.I`` is all it takes to make the case again.
"""

from __future__ import annotations

import fnmatch
import os
import random
import shutil
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from tests.fuzz import mutations as mu
from tests.fuzz.mutations import EITHER, GARBAGE, VALID, CsvSpec, Mutant, NpzSpec

#: seconds a case may run (a solve of 2 frames takes ~2 s; every solve has --max-seconds-per-frame 10)
CASE_TIMEOUT = 60.0
#: seconds a case whose input is a named pipe may run: opening the input must not block
PIPE_TIMEOUT = 10.0
ROOT = hasattr(os, "geteuid") and os.geteuid() == 0

M = "{B}/box.npz"
SIM = ("simulate", "--model", M, "--activations", "{B}/a.csv", "-o", "{C}/out", "--solver", "direct", "-q",
       "--max-seconds-per-frame", "10")
SOLVE = ("solve-mocap", "--model", M, "--markers", "{B}/markers.csv", "-o", "{C}/out", "--head", "none",
         "--max-steps", "1", "--solver", "direct", "-q", "--max-seconds-per-frame", "10")
RENDER = ("model", "render", M, "-o", "{C}/o.png", "--size", "160x160", "--no-legend")
CACHE = ("export-cache", "{B}/run", "--model", M, "--usd", "{C}/o.usda", "--pvd", "{C}/o.pvd", "--c3d", "{C}/o.c3d")
EXPORT = ("model", "export", M, "-o", "{C}/o.vtu", "--surfaces", "{C}/surfaces")
FIT = ("jaw", "fit", "--rig", "3dof", "--poses", "{B}/ext.npz", "-o", "{C}/rig.npz")
POSE = ("jaw", "pose", "--rig", "{B}/rp.npz", "--sliders", "0.5", "0", "0")
GENERATE = ("jaw", "generate", "--extremes", "-o", "{C}/p.npz")
FIT_MODEL = ("jaw", "fit-model", "--model", M, "-o", "{C}/rig.npz")
RETARGET = ("jaw", "retarget", "--rig", "{B}/rp.npz", "--poses", "{B}/ext.npz", "-o", "{C}/rig.npz")
ENVELOPE = ("jaw", "envelope", "--rig", "{B}/rp.npz", "-o", "{C}/env.png")
EDIT = ("edit", "scale", "{B}/a.csv", "--factor", "0.5", "--model", M, "-o", "{C}/out", "-q")


def set_option(argv, option: str, *values: str, drop: bool = False) -> list:
    """``argv`` with ``option``'s values replaced by ``values`` (appended if absent; removed with
    ``drop``). Values of an option are the words up to the next word starting with '--'."""
    argv = list(argv)
    if option in argv:
        k = argv.index(option)
        end = k + 1
        while end < len(argv) and not argv[end].startswith("--") and argv[end] not in ("-o", "-q"):
            end += 1
        argv[k:end] = [] if drop else [option, *values]
    elif not drop:
        argv += [option, *values]
    return argv


# ------------------------------------------------------------------ targets
@dataclass(frozen=True)
class Target:
    """One input of one command. ``argv``: the valid invocation, ``{X}`` where the input goes,
    ``{B}`` the bases' folder, ``{C}`` the case's; ``n``: cases per seed in CI; ``base_ok``: the
    valid invocation exits 0 (False: demo on the box model, which it refuses; VALID becomes
    EITHER)."""

    name: str
    argv: tuple
    n: int
    env: dict = field(default_factory=dict)
    base_ok: bool = True

    def operators(self) -> list:
        raise NotImplementedError

    def make(self, rng, op: str, case_dir: Path, base: Path) -> tuple[list, dict, Mutant]:
        raise NotImplementedError


@dataclass(frozen=True)
class FileTarget(Target):
    """A file input: ``base_file`` (in the bases' folder) mutated by ``ops`` (a table of
    :mod:`~tests.fuzz.mutations`) and written as ``input_name`` in the case folder."""

    base_file: str = ""
    input_name: str = ""
    ops: dict = field(default_factory=dict)
    spec: object = None
    exclude: tuple = ()
    copies: tuple = ()      # (source, name): unmutated files put beside the input

    def source(self, base: Path) -> Path:
        """The base file: in the bases' folder, or the shipped ``meshes/`` for ``meshes/NAME``."""
        if self.base_file.startswith("meshes/"):
            from facesim._files import MESHES

            return MESHES / self.base_file[len("meshes/"):]
        return base / self.base_file

    def operators(self):
        return [k for k in self.ops if k not in self.exclude]

    def make(self, rng, op, case_dir, base):
        spec = self.spec
        if isinstance(spec, str) and spec == "capture":
            import numpy as np

            with np.load(base / "capture.npz") as d:
                spec = mu.Capture(d["frames"], tuple(str(n) for n in d["names"]), d["P"])
        m = self.ops[op](rng, self.source(base).read_bytes(), spec)
        path = case_dir / self.input_name
        write_input(path, m)
        _copy(self, base, case_dir)
        return list(self.argv), dict(self.env), m


def _copy(target: FileTarget, base: Path, case_dir: Path) -> None:
    from facesim._files import MESHES

    for source, name in target.copies:
        shutil.copy(Path(source.replace("{B}", str(base)).replace("{M}", str(MESHES))), case_dir / name)


def write_input(path: Path, m: Mutant) -> None:
    if m.special == "missing":
        return
    if m.special == "dir":
        path.mkdir()
    elif m.special == "fifo":
        os.mkfifo(path)
    elif m.special == "loop":
        os.symlink(path.name, path)
    else:
        path.write_bytes(m.data)


@dataclass(frozen=True)
class OptionTarget(Target):
    """Option values: ``table`` of ``(changes, verdict)``, each change ``(option, *values)`` (a
    value ``None`` drops the option); ``{B}``/``{C}`` work in values too."""

    table: tuple = ()

    def operators(self):
        return [f"option:{k}" for k in range(len(self.table))]

    def make(self, rng, op, case_dir, base):
        changes, verdict = self.table[int(op.split(":")[1])]
        argv = list(self.argv)
        for option, *values in changes:
            argv = set_option(argv, option, drop=True) if values == [None] else set_option(argv, option, *values)
        words = " ".join(f"{o} {' '.join(repr(v) for v in vs)}".strip() for o, *vs in changes)
        name = f"option:{changes[0][0]}={'|'.join(str(v) for v in changes[0][1:])}"
        return argv, dict(self.env), Mutant(name, f"options changed: {words}", verdict)


#: valid --collider specs (the ball 80 mm in front of the box face, clear of it)
SPECS = ("sphere:radius=5,centre=0:0:80", "sphere:radius=5,path={B}/ball.csv", "capsule:radius=3,a=0:0:70,b=10:0:70",
         "plane:point=0:0:100,normal=0:0:-1", "mesh:file={B}/ball.obj,path={B}/ball.csv",
         "sphere:radius=5,centre=0:0:80,bone=jaw,name=ball")


def _spec_mutant(rng, case_dir: Path, base: Path) -> tuple[str, str, str]:
    """A mutated --collider spec: (op, spec, verdict)."""
    spec = rng.choice(SPECS)
    kind, _, rest = spec.partition(":")
    items = [s.split("=", 1) for s in rest.split(",")]
    how = rng.choice(("drop_key", "dup_key", "unknown_key", "kind", "no_colon", "empty", "vector", "number",
                      "normal_zero", "bone", "inside", "spacing", "scale", "file", "whitespace", "trailing_comma",
                      "relative_file"))
    required = {"sphere": {"radius"}, "capsule": {"radius", "a", "b"}, "plane": {"point", "normal"},
                "mesh": {"file"}}[kind]

    def join(k=kind, it=None):
        return f"{k}:" + ",".join("=".join(i) for i in (items if it is None else it))

    verdict = GARBAGE
    if how == "drop_key":
        k = rng.randrange(len(items))
        key = items[k][0]
        new = join(it=items[:k] + items[k + 1:])
        verdict = GARBAGE if key in required else EITHER
        how = f"drop_key:{key}"
    elif how == "dup_key":
        new = join(it=items + [items[0]])
    elif how == "unknown_key":
        new = join(it=items + [["colour", "red"]])
    elif how == "kind":
        k = rng.choice(("cube", "", "SPHERE", "sphere ", "spheres"))
        new = join(k=k) if kind == "sphere" else join(k=rng.choice(("cube", "")))
        verdict = EITHER if k in ("SPHERE", "sphere ") and kind == "sphere" else GARBAGE
        how = f"kind:{k.strip() or 'empty'}"
    elif how == "no_colon":
        new = spec.replace(":", " ", 1)
    elif how == "empty":
        new = rng.choice(("", ":", f"{kind}:", ",", "=", f"{kind}:,,,"))
    elif how in ("vector", "number", "spacing", "scale", "bone"):
        vectors = [k for k, (key, _) in enumerate(items) if key in ("centre", "a", "b", "point", "normal")]
        if how == "vector" and vectors:
            k = rng.choice(vectors)
            value = rng.choice(("1:2", "1:2:3:4", "nan:0:80", "inf:0:80", "1e30:0:80", "0:0:", "a:b:c", "0;0;80",
                                "1e400:0:0", ""))
            items[k] = [items[k][0], value]
            verdict = EITHER if value == "1e30:0:80" else GARBAGE
            how = f"vector:{value or 'empty'}"
        elif how == "number" or (how == "vector" and not vectors):
            value = rng.choice(("0", "-1", "nan", "inf", "1e30", "abc", "", "1e-30", "1e400"))
            items = [i for i in items if i[0] != "radius"] + [["radius", value]]
            kind = kind if kind in ("sphere", "capsule") else "sphere"
            if kind == "sphere" and not any(i[0] in ("centre", "path") for i in items):
                items.append(["centre", "0:0:80"])
            verdict = EITHER if value == "1e-30" else GARBAGE
            how = f"radius:{value or 'empty'}"
        elif how in ("spacing", "scale"):
            kind = "mesh"
            value = rng.choice(("0", "-1", "nan", "1e30", "0.05", "1e3") if how == "spacing" else
                               ("0", "-1", "nan", "1e30", "1e-9", "0.5"))
            items = [["file", "{B}/ball.obj"], ["path", "{B}/ball.csv"], [how, value]]
            verdict = EITHER if value in ("0.05", "1e3", "1e-9", "0.5") else GARBAGE
            how = f"{how}:{value}"
        else:
            value = rng.choice(("skull", "", "Cranium", "jaw", "world", "mandible"))
            items = [i for i in items if i[0] != "bone"] + [["bone", value]]
            verdict = EITHER if value in ("Cranium", "jaw", "world") else GARBAGE
            how = f"bone:{value or 'empty'}"
        new = join(k=kind)
    elif how == "normal_zero":
        new, verdict = "plane:point=0:0:100,normal=0:0:0", GARBAGE
    elif how == "inside":
        new, verdict = rng.choice((("sphere:radius=100,centre=0:0:0", GARBAGE), ("sphere:radius=3,centre=0:-20:20",
                                                                                 EITHER),
                                   ("plane:point=0:0:0,normal=0:0:-1", EITHER),
                                   ("capsule:radius=40,a=-100:0:0,b=100:0:0", GARBAGE)))
    elif how == "file":
        what = rng.choice(("missing", "dir", "text", "empty", "truncated", "open", "nan", "faces_oob", "flat"))
        path = case_dir / f"mesh_{what}.obj"
        text = (base / "ball.obj").read_text()
        lines = text.splitlines()
        if what == "dir":
            path.mkdir()
        elif what == "text":
            path.write_text("not a mesh\n")
        elif what == "empty":
            path.write_text("")
        elif what == "truncated":
            path.write_text(text[: len(text) // 3])
        elif what == "open":
            path.write_text("\n".join(ln for k, ln in enumerate(lines) if not (ln.startswith("f ") and k % 3 == 0)))
        elif what == "nan":
            path.write_text("v nan 0 0\n" + text.split("\n", 1)[1])
        elif what == "faces_oob":
            path.write_text(text + "f 1 2 9999\n")
        elif what == "flat":
            path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        new = f"mesh:file={path},path={{B}}/ball.csv"
        verdict = EITHER if what == "truncated" else GARBAGE
        how = f"file:{what}"
    elif how == "whitespace":
        new, verdict = " " + spec.replace(",", " , ").replace("=", " = ") + " ", EITHER
    elif how == "trailing_comma":
        new, verdict = spec + ",", EITHER
    else:
        new, verdict = "mesh:file=ball.obj,path=ball.csv", VALID   # relative to A.csv's folder (the bases)
    return f"spec:{how}", new, verdict


@dataclass(frozen=True)
class SpecTarget(Target):
    """``--collider SPEC`` strings."""

    def operators(self):
        return ["spec"]

    def make(self, rng, op, case_dir, base):
        op, spec, verdict = _spec_mutant(rng, case_dir, base)
        argv = list(self.argv) + ["--collider", spec]
        return argv, dict(self.env), Mutant(op, f"--collider {spec!r}", verdict)


@dataclass(frozen=True)
class OutputTarget(Target):
    """The output path (``-o`` or ``option``): ``kind`` ``"dir"`` or ``"file"`` with ``suffix``."""

    option: str = "-o"
    kind: str = "dir"
    suffix: str = ""

    def operators(self):
        return ["out:existing_file", "out:under_file", "out:existing_dir", "out:readonly", "out:long_name",
                "out:long_path", "out:drive", "out:empty", "out:proc", "out:unicode", "out:dot", "out:suffix_upper",
                "out:no_suffix", "out:trailing_slash", "out:newline"]

    def make(self, rng, op, case_dir, base):
        s, folder = self.suffix, self.kind == "dir"
        how = op.split(":")[1]
        verdict = GARBAGE
        if how == "existing_file":
            (case_dir / f"exists{s}").write_text("a file\n")
            value, verdict = f"{case_dir}/exists{s}", GARBAGE if folder else VALID
        elif how == "under_file":
            (case_dir / "afile").write_text("a file\n")
            value = f"{case_dir}/afile/out{s}"
        elif how == "existing_dir":
            (case_dir / f"adir{s}").mkdir()
            value, verdict = f"{case_dir}/adir{s}", VALID if folder else GARBAGE
        elif how == "readonly":
            (case_dir / "ro").mkdir()
            os.chmod(case_dir / "ro", 0o555)
            value, verdict = f"{case_dir}/ro/out{s}", EITHER if ROOT else GARBAGE
        elif how == "long_name":
            value = f"{case_dir}/{'n' * 300}{s}"
        elif how == "long_path":
            value = f"{case_dir}/" + "/".join(["d" * 200] * 25) + f"/out{s}"
        elif how == "drive":
            value, verdict = f"Q:\\out\\x{s}" if rng.random() < 0.5 else f"Q:/out/x{s}", EITHER
        elif how == "empty":
            value = ""
        elif how == "proc":
            value = f"/proc/facesim-fuzz/out{s}"
        elif how == "unicode":
            value, verdict = f"{case_dir}/r\u00e9sultat \u00fc{s}", VALID
        elif how == "dot":
            value, verdict = ".", EITHER if folder else GARBAGE
        elif how == "suffix_upper":
            value, verdict = f"{case_dir}/o{s.upper()}", VALID if folder else EITHER
        elif how == "no_suffix":
            value, verdict = f"{case_dir}/o", VALID if folder else GARBAGE
        elif how == "trailing_slash":
            value, verdict = f"{case_dir}/o{s}/", EITHER   # pathlib drops the slash
        else:
            value, verdict = f"{case_dir}/o\nx{s}", EITHER
        argv = set_option(self.argv, self.option, value)
        return argv, dict(self.env), Mutant(op, f"{self.option} {value[:80]!r}" + ("..." if len(value) > 80 else ""),
                                            verdict)


@dataclass(frozen=True)
class ArgvTarget(Target):
    """Whole invocations, each refused whatever happens (``model build``: never build a model)."""

    table: tuple = ()

    def operators(self):
        return [f"argv:{k}" for k in range(len(self.table))]

    def make(self, rng, op, case_dir, base):
        argv = list(self.table[int(op.split(":")[1])])
        return argv, dict(self.env), Mutant(f"argv:{' '.join(argv[2:])[:40]}", "argv " + " ".join(argv), GARBAGE)


# ------------------------------------------------------------------ the target list
ACT = CsvSpec({"frame": "frame", "zygomaticus_major_L": "unit", "orbicularis_oris": "unit"},
              optional=frozenset({"zygomaticus_major_L", "orbicularis_oris"}))
JAW = CsvSpec({"frame": "frame"}, same_frames=True)
BALL = CsvSpec({"frame": "frame", "x": "far", "y": "far", "z": "far"})
MARKERS = CsvSpec({"frame": "frame"}, markers=True)
for _c in ("mouth_L", "mouth_R", "chin", "cheek_L", "head_L", "head_R"):
    MARKERS.roles.update({f"{_c}_{a}": "coord" for a in "xyz"})
MODEL = NpzSpec()
POSES = NpzSpec(optional=frozenset({"reference_point", "names", "segment_names", "segment_bounds"}),
                unread=frozenset({"times", "latent"}))
EXTREMES = NpzSpec(optional=POSES.optional, unread=POSES.unread, extremes=True)
RIG = NpzSpec(unbounded=frozenset({"bounds"}))   # a classic rig fitted without a range is unbounded

G, E, V = GARBAGE, EITHER, VALID


def _model_target(name, argv, n, **kw):
    return FileTarget(name, argv, n, base_file="box.npz", input_name="m.npz", ops=mu.MODEL_OPS, spec=MODEL, **kw)


def targets() -> list[Target]:
    """Every target, in the order cases are made."""
    sim, solve = list(SIM), list(SOLVE)
    t = [
        # model files
        _model_target("model info", ("model", "info", "{C}/m.npz"), 8),
        _model_target("model info --json", ("model", "info", "{C}/m.npz", "--json"), 3),
        _model_target("model export", tuple(set_option(EXPORT[:2] + ("{C}/m.npz",) + EXPORT[3:], "-o",
                                                       "{C}/o.vtu")), 5),
        _model_target("model render", ("model", "render", "{C}/m.npz", "-o", "{C}/o.png", "--size", "160x160",
                                       "--no-legend"), 4),
        _model_target("simulate.model", tuple(set_option(sim, "--model", "{C}/m.npz")), 6),
        _model_target("solve-mocap.model", tuple(set_option(solve, "--model", "{C}/m.npz")), 5),
        _model_target("jaw generate.model", ("jaw", "generate", "--model", "{C}/m.npz", "--extremes", "-o",
                                             "{C}/p.npz"), 3),
        _model_target("jaw fit-model.model", tuple(set_option(FIT_MODEL, "--model", "{C}/m.npz")), 3),
        _model_target("export-cache.model", tuple(set_option(CACHE, "--model", "{C}/m.npz")), 3),
        _model_target("demo.FACESIM_MODEL", ("demo", "-o", "{C}/demo", "--frames", "0:0", "-q"), 4,
                      env={"FACESIM_MODEL": "{C}/m.npz"}, base_ok=False,
                      exclude=("npz:extra", "npz:uncompressed")),
        FileTarget("demo.clip truth", ("demo", "--clip", "{C}/clip.c3d", "-o", "{C}/demo", "--frames", "0:0", "-q"),
                   3, env={"FACESIM_MODEL": M}, base_ok=False, base_file="meshes/demo_clip_truth.npz",
                   input_name="clip_truth.npz", ops=mu.NPZ_OPS, spec=NpzSpec(),
                   copies=(("{M}/demo_clip.c3d", "clip.c3d"),)),
        # controls
        FileTarget("simulate.activations", tuple(set_option(sim, "--activations", "{C}/a.csv")), 10,
                   base_file="a.csv", input_name="a.csv", ops=mu.CSV_OPS, spec=ACT),
        FileTarget("simulate.jaw.opening", tuple(sim + ["--jaw", "{C}/j.csv"]), 6, base_file="j_open.csv",
                   input_name="j.csv", ops=mu.CSV_OPS, spec=JAW),
        FileTarget("simulate.jaw.full", tuple(sim + ["--jaw", "{C}/j.csv"]), 5, base_file="j_full.csv",
                   input_name="j.csv", ops=mu.CSV_OPS, spec=JAW),
        FileTarget("simulate.jaw.sliding", tuple(sim + ["--jaw", "{C}/j.csv", "--jaw-model", "sliding-condyle"]), 5,
                   base_file="j_slide.csv", input_name="j.csv", ops=mu.CSV_OPS, spec=JAW),
        FileTarget("simulate.jaw.posselt", tuple(sim + ["--jaw", "{C}/j.csv", "--jaw-model",
                                                        "posselt:{B}/box_posselt.npz"]), 4,
                   base_file="j_posselt.csv", input_name="j.csv", ops=mu.CSV_OPS, spec=JAW),
        # colliders
        SpecTarget("simulate.collider", tuple(sim), 10),
        SpecTarget("solve-mocap.collider", tuple(solve), 3),
        FileTarget("simulate.collider.path", tuple(sim + ["--collider", "sphere:radius=5,path={C}/ball.csv"]), 5,
                   base_file="ball.csv", input_name="ball.csv", ops=mu.CSV_OPS, spec=BALL),
        FileTarget("simulate.collider.mesh", tuple(sim + ["--collider", "mesh:file={C}/ball.obj,path={B}/ball.csv"]),
                   4, base_file="ball.obj", input_name="ball.obj",
                   ops={k: mu.FILE_OPS[k] for k in ("file:missing", "file:dir", "file:fifo", "file:empty", "file:text",
                                                     "file:binary", "file:truncate", "file:flip")}),
        # captures
        FileTarget("solve-mocap.markers.csv", tuple(set_option(solve, "--markers", "{C}/markers.csv")), 8,
                   base_file="markers.csv", input_name="markers.csv", ops=mu.CSV_OPS, spec=MARKERS),
        FileTarget("solve-mocap.markers.trc", tuple(set_option(solve, "--markers", "{C}/markers.trc")), 8,
                   base_file="markers.trc", input_name="markers.trc", ops=mu.TRC_OPS),
        FileTarget("solve-mocap.markers.c3d", tuple(set_option(solve, "--markers", "{C}/markers.c3d")), 6,
                   base_file="markers.c3d", input_name="markers.c3d", ops=mu.C3D_OPS, spec="capture"),
        FileTarget("edit.source", tuple(EDIT[:2] + ("{C}/a.csv",) + EDIT[3:]), 6, base_file="a.csv",
                   input_name="a.csv", ops=mu.CSV_OPS, spec=ACT),
        # jaw poses
        FileTarget("jaw fit.poses", tuple(set_option(FIT, "--poses", "{C}/p.npz")), 4, base_file="ext.npz",
                   input_name="p.npz", ops=mu.POSES_OPS, spec=POSES),
        FileTarget("jaw fit posselt.poses", tuple(set_option(set_option(FIT, "--poses", "{C}/p.npz"), "--rig",
                                                             "posselt")), 3,
                   base_file="ses.npz", input_name="p.npz", ops=mu.POSES_OPS, spec=POSES),
        FileTarget("jaw eval.poses", ("jaw", "eval", "--rig", "{B}/r3.npz", "--poses", "{C}/p.npz"), 4,
                   base_file="ext.npz", input_name="p.npz", ops=mu.POSES_OPS, spec=POSES),
        FileTarget("jaw retarget.poses", tuple(set_option(RETARGET, "--poses", "{C}/p.npz")), 4,
                   base_file="ext.npz", input_name="p.npz", ops=mu.POSES_OPS, spec=EXTREMES),
        FileTarget("jaw envelope.poses", tuple(ENVELOPE + ("--poses", "{C}/p.npz")), 2,
                   base_file="ext.npz", input_name="p.npz", ops=mu.POSES_OPS, spec=POSES),
        # jaw rigs
        FileTarget("jaw eval.rig", ("jaw", "eval", "--rig", "{C}/rig.npz", "--poses", "{B}/ext.npz"), 3,
                   base_file="r3.npz", input_name="rig.npz", ops=mu.RIG_OPS, spec=RIG),
        FileTarget("jaw pose.rig", tuple(set_option(POSE, "--rig", "{C}/rig.npz")), 4,
                   base_file="rp.npz", input_name="rig.npz", ops=mu.RIG_OPS, spec=RIG),
        FileTarget("jaw envelope.rig", tuple(set_option(ENVELOPE, "--rig", "{C}/rig.npz")), 2,
                   base_file="rn.npz", input_name="rig.npz", ops=mu.RIG_OPS, spec=RIG),
        FileTarget("jaw retarget.rig", tuple(set_option(RETARGET, "--rig", "{C}/rig.npz")), 3,
                   base_file="rp.npz", input_name="rig.npz", ops=mu.RIG_OPS, spec=RIG),
        FileTarget("simulate.jaw-model.rig", tuple(sim + ["--jaw", "{B}/j_posselt.csv", "--jaw-model",
                                                          "posselt:{C}/rig.npz"]), 3,
                   base_file="box_posselt.npz", input_name="rig.npz", ops=mu.RIG_OPS, spec=RIG),
        # options
        OptionTarget("model render.options", RENDER, 5, table=RENDER_OPTIONS),
        OptionTarget("simulate.options", tuple(sim), 6, table=SIMULATE_OPTIONS),
        OptionTarget("solve-mocap.options", tuple(solve), 8, table=SOLVE_OPTIONS),
        OptionTarget("jaw fit.options", FIT, 2, table=FIT_OPTIONS),
        OptionTarget("jaw pose.options", POSE, 2, table=POSE_OPTIONS),
        OptionTarget("jaw generate.options", GENERATE, 3, table=GENERATE_OPTIONS),
        OptionTarget("jaw fit-model.options", FIT_MODEL, 1, table=FIT_MODEL_OPTIONS),
        OptionTarget("jaw retarget.options", RETARGET, 1, table=RETARGET_OPTIONS),
        OptionTarget("export-cache.options", CACHE, 3, table=CACHE_OPTIONS),
        OptionTarget("edit.options", EDIT, 3, table=EDIT_OPTIONS),
        ArgvTarget("model build", (), 3, table=BUILD_ARGV),
        # output paths
        OutputTarget("simulate.output", tuple(sim), 3),
        OutputTarget("solve-mocap.output", tuple(solve), 2),
        OutputTarget("model render.output", RENDER, 1, kind="file", suffix=".png"),
        OutputTarget("model export.output", EXPORT, 1, kind="file", suffix=".vtu"),
        OutputTarget("model export.surfaces", EXPORT, 1, option="--surfaces"),
        OutputTarget("jaw fit.output", FIT, 1, kind="file", suffix=".npz"),
        OutputTarget("jaw generate.output", GENERATE, 1, kind="file", suffix=".npz"),
        OutputTarget("jaw envelope.output", ENVELOPE, 1, kind="file", suffix=".png"),
        OutputTarget("export-cache.usd", CACHE, 1, option="--usd", kind="file", suffix=".usda"),
        OutputTarget("export-cache.pvd", CACHE, 1, option="--pvd", kind="file", suffix=".pvd"),
        OutputTarget("edit.output", EDIT, 1),
    ]
    return t


CACHE_OPTIONS = (
    ((("--fps", "0"),), G), ((("--fps", "-1"),), G), ((("--fps", "nan"),), G), ((("--fps", "abc"),), G),
    ((("--fps", "24"),), V), ((("--usd", "{C}/o.txt"),), G), ((("--pvd", "{C}/o.vtu"),), G),
    ((("--c3d", "{C}/o.csv"),), G), ((("--usd", None), ("--pvd", None), ("--c3d", None)), G),
    ((("--usd", "{C}/o.usd"),), V), ((("--usd", "{C}/o.usdc"),), V), ((("--model", "{B}/nothing.npz"),), G),
    ((("--model", "{M}/face_coarse.npz"),), G),   # another model than the run's
    ((("--output-frame", "input"),), G),   # the box model was not imported: no input frame
    ((("--output-frame", "facesim"),), V), ((("--output-frame", "world"),), G),
)
RENDER_OPTIONS = (
    ((("--size", "0x0"),), G), ((("--size", "16x16"),), V), ((("--size", "100000x1"),), G),
    ((("--size", "1x100000"),), G), ((("--size", "abc"),), G), ((("--size", "-160x-160"),), G),
    ((("--size", "160x160x3"),), G), ((("--size", "160X160"),), E), ((("--size", " 160x160 "),), E),
    ((("--size", "1e3x1e3"),), G), ((("--size", "8192x16"),), E), ((("--size", ""),), G),
    ((("--opacity", "nan"),), G), ((("--opacity", "-0.1"),), G), ((("--opacity", "1.1"),), G),
    ((("--opacity", "inf"),), G), ((("--opacity", "0"),), V), ((("--opacity", "1"),), V), ((("--opacity", "abc"),), G),
    ((("--view", "back"),), G), ((("--view", "side"),), V), ((("--hide", "hair"),), G),
    ((("--hide", "skin,skin"),), E), ((("--hide", ","),), E), ((("--hide", "skin,bones,colliders,muscles,markers"),), E),
    ((("--sheet",), ("--size", "16x16"), ("-q",)), E), ((("--no-legend", None),), V), ((("--size", "16x8192"),), E),
)
SIMULATE_OPTIONS = (
    ((("--controls-from", "{B}/run"), ("--activations", None)), G),   # a simulate run, not a solve
    ((("--controls-from", "{B}"), ("--activations", None)), G), ((("--controls-from", "{C}/nothing"),), G),
    ((("--controls-from", "{B}/run"),), G),   # with --activations too
    ((("--activations", None),), G),
    ((("--fps", "0"),), G), ((("--fps", "-1"),), G), ((("--fps", "nan"),), G), ((("--fps", "inf"),), G),
    ((("--fps", "1e300"),), G), ((("--fps", "x"),), G), ((("--fps", "10000"),), V), ((("--fps", "0.001"),), V),
    ((("--max-seconds-per-frame", "0"),), G), ((("--max-seconds-per-frame", "-1"),), G),
    ((("--max-seconds-per-frame", "nan"),), G), ((("--max-seconds-per-frame", "inf"),), E),
    ((("--max-seconds-per-frame", "1e-9"),), E), ((("--max-seconds-per-frame", "x"),), G),
    ((("--contact-stiffness", "-1"),), G), ((("--contact-stiffness", "nan"),), G),
    ((("--contact-stiffness", "inf"),), G), ((("--contact-stiffness", "0"),), E),
    ((("--contact-stiffness", "1e30"),), E), ((("--contact-stiffness", "x"),), G),
    ((("--solver", "cg"),), G), ((("--jaw-model", "nlpca"),), G), ((("--jaw-model", "posselt:"),), G),
    ((("--jaw-model", "posselt:{C}/none.npz"),), G), ((("--jaw-model", "classic:{B}/r3.npz"),), E),
    ((("--jaw-model", "foo"),), G), ((("--jaw-model", ""),), G), ((("--jaw-model", "posselt"),), E),
    ((("--jaw-model", "nlpca:{B}/rp.npz"),), G),
    ((("--jaw-model", "sliding-condyle"), ("--jaw", "{B}/j_open.csv")), G),
    ((("--jaw", "{B}/j_slide.csv"),), G), ((("--jaw", "{B}/j_posselt.csv"),), G),
    ((("--jaw", "{B}/a.csv"),), G), ((("--activations", "{B}/j_open.csv"),), G),
    ((("--activations", "{B}/markers.csv"),), G), ((("--jaw", "{B}/ball.csv"),), G),
    ((("--size", "0x0"),), G), ((("--view", "back"),), G), ((("--resume",),), E),
    ((("--resume",), ("--overwrite",)), G), ((("--render",), ("--size", "16x16")), E),
    ((("--teeth-contact",),), E), ((("--lip-contact",),), E), ((("--activations", None),), G),
    ((("--model", None),), G), ((("-o", None),), G), ((("--collider", ""),), G), ((("--frobnicate", "1"),), G),
    ((("--model", "{B}/a.csv"),), G), ((("--model", "{B}/rp.npz"),), G),
    ((("--output-frame", "input"),), G), ((("--output-frame", ""),), G),   # the box model has no input frame
)
SOLVE_OPTIONS = (
    ((("--layout", "capture"),), E), ((("--layout", "model"), ("--head-markers", "head_L,head_R")), G),
    ((("--head-markers", "nope,none,nil"),), G), ((("--head-markers", ","),), G),
    ((("--marker-map", "{C}/nothing.csv"),), G), ((("--marker-map", "{B}/a.csv"),), G),
    ((("--layout", "sideways"),), G), ((("--write-meshes",),), V),
    ((("--noise", "0"),), G), ((("--noise", "-1"),), G), ((("--noise", "nan"),), G), ((("--noise", "inf"),), G),
    ((("--noise", "1e30"),), E), ((("--noise", "x"),), G),
    ((("--max-steps", "0"),), E), ((("--max-steps", "-1"),), G), ((("--max-steps", "x"),), G),
    ((("--max-steps", "1.5"),), G), ((("--max-steps", "99999999999999999999"),), E),
    ((("--loss-scale", "0"),), G), ((("--loss-scale", "-1"),), G), ((("--loss-scale", "nan"),), G),
    ((("--loss-scale", "inf"),), G), ((("--loss", "huber"),), V), ((("--loss", "cauchy"), ("--loss-scale", "1")), V),
    ((("--head-smoothing", "2"),), G), ((("--head-smoothing", "-1"),), G), ((("--head-smoothing", "1"),), E),
    ((("--head-smoothing", "3"),), E), ((("--head-smoothing", "x"),), G),
    ((("--head-smoothing", "1000000001"),), E),
    ((("--frames", "1:0"),), G), ((("--frames", "5:9"),), G), ((("--frames", "a:b"),), G), ((("--frames", ""),), G),
    ((("--frames", ":"),), V), ((("--frames", "0"),), V), ((("--frames", "-1"),), G), ((("--frames", "0:0:0"),), G),
    ((("--frames", "1e3"),), G), ((("--frames", "0:99999999999999999999999"),), E), ((("--frames", "1:"),), V),
    ((("--bind-frames", "0:0"),), E), ((("--bind-frames", "9:9"),), G), ((("--bind-frames", "x"),), G),
    ((("--bind-frames", ""),), G),
    ((("--chunk-size", "0"),), G), ((("--chunk-size", "-1"),), G), ((("--chunk-size", "1"),), E),
    ((("--chunk-size", "x"),), G), ((("--workers", "0"),), G), ((("--workers", "-1"),), G),
    ((("--workers", "x"),), G),
    ((("--units", "cm"),), G), ((("--units", "m"),), G), ((("--units", "mm"),), V), ((("--units", "in"),), G),
    ((("--jaw-model", "rigid"),), E), ((("--jaw-model", "nlpca"),), G), ((("--jaw-model", "posselt:{C}/none.npz"),), G),
    ((("--jaw-model", ""),), G), ((("--jaw-model", "posselt:{B}/box_posselt.npz"),), E),
    ((("--jaw-model", "nlpca:{B}/rp.npz"),), G), ((("--head", "procrustes"),), E),
    ((("--contact-stiffness", "-1"),), G), ((("--contact-stiffness", "nan"),), G),
    ((("--contact-stiffness", "inf"),), G), ((("--no-contact",), ("--lip-contact",)), G),
    ((("--scheduler", "not-an-address"),), G), ((("--resume",),), E), ((("--markers", None),), G),
    ((("--markers", "{B}/a.csv"),), G), ((("--markers", "{B}/box.npz"),), G), ((("--markers", "{B}/markers.c3d"),), V),
    ((("--markers", "{B}/markers.trc"), ("--units", "cm")), G),
    ((("--head", "solve"),), E), ((("--head", "solve"), ("--head-smoothing", "3")), E),
    ((("--head", "solve"), ("--write-meshes",)), E), ((("--head", "tilt"),), G),
    ((("--write-meshes",), ("--output-frame", "input")), G), ((("--output-frame", "input"),), V),   # ignored: a warning
)
EDIT_OPTIONS = (
    ((("--factor", "-1"),), G), ((("--factor", "nan"),), G), ((("--factor", "inf"),), G), ((("--factor", "x"),), G),
    ((("--factor", "1e300"),), G), ((("--factor", "0"),), V), ((("--factor", "2"),), V),
    ((("--muscles", "nope"),), G), ((("--muscles", ","),), G), ((("--muscles", "zygomaticus_major_L"),), V),
    ((("--source-fps", "0"),), G), ((("--source-fps", "nan"),), G), ((("--source-fps", "-5"),), G),
    ((("--jaw", "{B}/a.csv"),), G), ((("--jaw", "{C}/nothing.csv"),), G), ((("--model", "{B}/a.csv"),), G),
    ((("--model", None),), G), ((("-o", None),), G), ((("--jaw-model", "foo"),), G), ((("--simulate",),), E),
    ((("--resume",),), E), ((("--resume",), ("--overwrite",)), G),
)
FIT_OPTIONS = (
    ((("--iterations", "0"),), G), ((("--iterations", "-1"),), G), ((("--iterations", "x"),), G),
    ((("--iterations", "1e3"),), G), ((("--seed", "-1"),), E), ((("--seed", "x"),), G), ((("--rig", "foo"),), G),
    ((("--rig", "nlpca"),), G), ((("--rig", "posselt"),), E), ((("--rig", "1dof"),), V), ((("--rig", "6dof"),), E),
    ((("--poses", "{B}/rp.npz"),), G), ((("--poses", "{B}/box.npz"),), G), ((("--poses", "{B}/a.csv"),), G),
)
POSE_OPTIONS = (
    ((("--sliders", "nan", "0", "0"),), G), ((("--sliders", "inf", "0", "0"),), G), ((("--sliders", "2", "0", "0"),), G),
    ((("--sliders", "-0.1", "0", "0"),), G), ((("--sliders", "-0", "0", "0"),), V), ((("--sliders", "0.5", "0.5"),), G),
    ((("--sliders", "0.5", "0.5", "0.5", "0.5"),), G), ((("--sliders", "x"),), G),
    ((("--sliders", "1e-320", "0", "0"),), V), ((("--sliders", "1", "1", "1"),), V),
    ((("--rig", "{B}/r3.npz"), ("--sliders", "10", "10", "10")), G),
    ((("--rig", "{B}/rn.npz"), ("--sliders", "0", "0", "0")), E),
    ((("--rig", "{B}/rn.npz"), ("--sliders", "1e30", "0", "0")), G),
    ((("--rig", "{B}/r3.npz"), ("--sliders", "nan", "0", "0")), G), ((("--rig", "{B}/ext.npz"),), G),
    ((("--rig", "{B}/box.npz"),), G),
)
GENERATE_OPTIONS = (
    ((("--subject", "-1"),), E), ((("--subject", "1180591620717411303424"),), E), ((("--subject", "x"),), G),
    ((("--session", "-1"),), E), ((("--session", "18446744073709551617"),), E), ((("--noise", "-1"),), G),
    ((("--noise", "nan"),), G), ((("--noise", "inf"),), G), ((("--noise", "1e30"),), G), ((("--noise", "1e3"),), E),
    ((("--extremes", None), ("--kinds", "dance")), G), ((("--extremes", None), ("--kinds", "border", "border")), E),
    ((("--extremes", None), ("--noise", "1e30")), G), ((("--model", "{B}/a.csv"),), G),
    ((("--model", "{B}/rp.npz"),), G),
)
FIT_MODEL_OPTIONS = (
    ((("--session", "-1"),), E), ((("--noise", "-1"),), G), ((("--noise", "nan"),), G), ((("--noise", "1e30"),), G),
    ((("--noise", "1e3"),), E), ((("--noise", "x"),), G), ((("--model", "{B}/rp.npz"),), G),
)
RETARGET_OPTIONS = (
    ((("--mode", "reduced"),), V), ((("--mode", "none"),), V), ((("--mode", "x"),), G),
    ((("--rig", "{B}/r3.npz"),), G), ((("--rig", "{B}/rn.npz"),), G), ((("--poses", "{B}/ses.npz"),), E),
)
BUILD_ARGV = (
    ("model", "build", "-o", "{C}/m.txt"),
    ("model", "build", "--resolution", "huge", "-o", "{C}/m.npz"),
    ("model", "build", "--seed", "x", "-o", "{C}/m.npz"),
    ("model", "build", "--refine", "-1", "--mesh-from", M, "-o", "{C}/m.npz"),
    ("model", "build", "--refine", "1", "-o", "{C}/m.npz"),
    ("model", "build", "--refine", "x", "-o", "{C}/m.npz"),
    ("model", "build", "--mesh-from", "{C}/missing.npz", "--resolution", "test", "-o", "{C}/m.npz"),
    ("model", "build", "--mesh-from", M, "--resolution", "test", "-o", "{C}/m.npz"),
    ("model", "build", "--mesh-from", M, "--resolution", "test", "--seed", "1", "-o", "{C}/m.npz"),
    ("model", "build", "--mesh-from", "{B}/a.csv", "--resolution", "test", "-o", "{C}/m.npz"),
    ("model", "build", "--mesh-from", "{B}/rp.npz", "--resolution", "test", "-o", "{C}/m.npz"),
    ("model", "build", "--resolution", "test", "-o", ""),
)


# ------------------------------------------------------------------ cases
def _offset(name: str, n_ops: int, seed: int) -> int:
    return (zlib.crc32(name.encode()) + 7919 * seed) % n_ops


def _fill(words, base: Path, case_dir: Path) -> list:
    return [w.replace("{B}", str(base)).replace("{C}", str(case_dir)) for w in words]


def make_cases(seed: int, base: Path, work: Path, scale: int = 1, only: str | None = None) -> list[dict]:
    """The cases of ``seed``: ``scale * target.n`` per target, each with its input written under
    ``work``, after the valid invocation of every target (op ``none``, id ``TARGET#base``: it must
    succeed). ``only``: a case id, or a glob of them (``'simulate.*'``)."""
    base, work = Path(base), Path(work)
    cases, seen = [], set()
    for target in targets():
        ops = target.operators()
        ids = [(f"{target.name}#base", None)] + [(f"{target.name}#{seed}.{i}", i) for i in range(target.n * scale)]
        for case_id, i in ids:
            if only is not None and not fnmatch.fnmatchcase(case_id, only):
                continue
            if i is None and (not target.base_ok or isinstance(target, ArgvTarget) or
                              (not isinstance(target, FileTarget) and target.argv in seen)):
                continue
            case_dir = work / f"{len(cases):05d}"
            if case_dir.exists():
                shutil.rmtree(case_dir)
            case_dir.mkdir(parents=True)
            if i is None:
                seen.add(target.argv)
                argv, env = _base_argv(target, base, case_dir), dict(target.env)
                m = Mutant("none", "the valid invocation", VALID)
            else:
                rng = random.Random(f"{seed}/{target.name}/{i}")
                op = ops[(i + _offset(target.name, len(ops), seed)) % len(ops)]
                argv, env, m = target.make(rng, op, case_dir, base)
            verdict = m.verdict if target.base_ok or m.verdict != VALID else EITHER
            cases.append({"id": case_id, "target": target.name, "op": m.op, "what": m.what, "verdict": verdict,
                          "argv": _fill(argv, base, case_dir),
                          "env": {k: _fill([v], base, case_dir)[0] for k, v in env.items()},
                          "cwd": str(case_dir), "timeout": PIPE_TIMEOUT if m.special == "fifo" else CASE_TIMEOUT})
    return cases


def _base_argv(target: Target, base: Path, case_dir: Path) -> list:
    """The target's invocation on the unmutated base file (copied where the mutant would go)."""
    if isinstance(target, FileTarget):
        shutil.copy(target.source(base), case_dir / target.input_name)
        _copy(target, base, case_dir)
    return list(target.argv)


__all__ = ["CASE_TIMEOUT", "Target", "make_cases", "set_option", "targets"]
