"""Animation caches of a finished run, for other tools: USD (DCC tools), a ParaView ``.pvd`` series
of ``.vtu`` volumes, and a C3D of the simulated markers.

Every writer takes the model and a :class:`Run` -- the solved frames, read from a folder written
by ``facesim simulate`` (or ``solve-mocap --write-meshes``: the same ``state/frame_KKKKK.npz``
files) with :func:`read_run`, or built from arrays in memory with :meth:`Run.from_arrays` -- so
it runs at the end of a run or on its own (``facesim export-cache``). :func:`export_cache` writes
the ones asked for from a folder.

* :func:`write_usd` -- one ``.usd`` / ``.usda`` / ``.usdc`` stage: the skin as a time-sampled
  ``UsdGeom.Mesh`` (points per frame, topology once), the cranium and jaw surfaces under two
  ``Xform`` prims whose transform is time-sampled (fitted to the bone's attached nodes with
  :func:`facesim.se3.rigid_fit`, so any jaw model works), the markers as ``UsdGeom.Points``, the
  activations per frame as ``facesim:activations``. Time code = frame number; mm
  (``metersPerUnit`` 0.001), y up. USD stores points as float32 (~1e-5 mm at face size).
* :func:`write_pvd` -- ``OUT.pvd`` and ``OUT/frame_KKKKK.vtu``: deformed tets with point data
  ``displacement`` (x - X, mm), cell data ``activation`` (sum over the tet's muscle entries of
  fraction * a), ``active_stress`` (the same weighted by ``sigma_max``, MPa), ``tissue``,
  ``muscle`` (dominant, -1 none); the muscle and tissue names in field data as one array per
  name (``muscle:<name>`` = [index], ``tissue:<name>`` = [label]: meshio reads numeric field
  data only, and its writer drops field data, so it is added to the XML here). Timestep =
  frame / fps s.
* :func:`write_markers_c3d` -- a C3D of marker trajectories; frame numbers missing from the
  sequence are written as frames of missing markers (C3D is uniformly sampled).

Positions are those of facesim's frame (mm, y up), or, with an
:class:`~facesim.output_frame.OutputFrame` ``frame`` (``export-cache --output-frame input``), of
the user's input frame and units of an imported model: USD then declares that unit
(``metersPerUnit``) and the input axis nearest to up (``upAxis``), and the bone transforms are the
same motions in that frame; the ``.pvd`` displacements are in that frame too; the C3D declares
the unit.

A frame that did not converge (``converged`` false in its state, or non-finite positions) is
not shown: USD gets the last converged frame's values again at its time code (USD interpolates
linearly between samples, so leaving the sample out would show a blend, not a hold), the ``.pvd``
entry points at the last converged frame's ``.vtu``; before any converged frame, the rest pose.
Both record the frame numbers (USD: ``customLayerData["facesim"]["unconverged_frames"]``, PVD:
an XML comment and field data ``converged`` per ``.vtu``). Markers of such frames are missing.
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable
from xml.sax.saxutils import quoteattr

import numpy as np

import facesim
from facesim._files import atomic_write, open_npz, require_suffix
from facesim.errors import FacesimError
from facesim.model import FaceModel
from facesim.output_frame import FACESIM, output_frame as output_frame_of, run_output_frame

USD_SUFFIXES = (".usd", ".usda", ".usdc")
#: Frame rate when neither the caller nor the run's report.json gives one (Hz).
DEFAULT_FPS = 30.0
_STATE = re.compile(r"frame_(\d+)\.npz$")
_PXR_MISSING = "USD caches need the pxr module: pip install usd-core"


# ------------------------------------------------------------------ the frames of a run
@dataclass(frozen=True)
class Run:
    """The solved frames of a run, read one at a time.

    frames : (F,) int64 increasing frame numbers; fps : the run's frame rate (Hz) if known, else
    None; load : ``load(i) -> (x (n, 3) float64 mm, a (n_muscles,) float64, converged bool)`` of
    the i-th frame; source : what it was read from (for messages).
    """

    frames: np.ndarray
    load: Callable[[int], tuple[np.ndarray, np.ndarray, bool]]
    fps: float | None = None
    source: str = "frames"

    def __len__(self) -> int:
        return len(self.frames)

    @staticmethod
    def from_arrays(frames, x, a, converged=None, fps: float | None = None) -> "Run":
        """A run held in memory: ``frames (F,)``, ``x (F, n, 3)`` mm, ``a (F, n_muscles)``,
        ``converged (F,)`` bool (default all true)."""
        frames = np.asarray(frames, dtype=np.int64)
        x, a = np.asarray(x, dtype=np.float64), np.asarray(a, dtype=np.float64)
        ok = np.ones(len(frames), bool) if converged is None else np.asarray(converged, bool)
        if x.ndim != 3 or x.shape[2] != 3 or len(x) != len(frames) or len(a) != len(frames) or ok.shape != frames.shape:
            raise FacesimError(f"run: expected x (F, n, 3), a (F, m) and converged (F,) for {len(frames)} frames, got "
                               f"{x.shape}, {a.shape}, {ok.shape}")
        _check_frames(frames, "run")
        return Run(frames, lambda i: (x[i], a[i], bool(ok[i]) and bool(np.isfinite(x[i]).all())), fps)


def _check_frames(frames: np.ndarray, where: str) -> None:
    if not len(frames):
        raise FacesimError(f"{where}: no frames")
    if np.any(np.diff(frames) <= 0):
        raise FacesimError(f"{where}: frame numbers must increase")


def _listed_frames(path: Path) -> np.ndarray:
    """The frame numbers of a run's ``frames.csv`` (its ``frame`` column: the complete frames)."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as exc:
        raise FacesimError(f"{path}: cannot read the frame log ({exc})") from None
    if not rows or "frame" not in rows[0]:
        raise FacesimError(f"{path}: expected a frame log with a 'frame' column (written by facesim simulate)")
    j = rows[0].index("frame")
    try:
        return np.array([int(r[j]) for r in rows[1:] if r], dtype=np.int64)
    except (ValueError, IndexError):
        raise FacesimError(f"{path}: a row without an integer frame number") from None


def _report(folder: Path) -> dict | None:
    """The run's ``report.json``, None when it has none or it is unreadable."""
    try:
        report = json.loads((folder / "report.json").read_text())
    except (OSError, ValueError):
        return None
    return report if isinstance(report, dict) else None


def _run_fps(folder: Path) -> float | None:
    """The frame rate the run recorded in ``report.json`` (``options.fps``, else ``fps``), if any."""
    report = _report(folder)
    fps = (report.get("options") or {}).get("fps", report.get("fps")) if isinstance(report, dict) else None
    return float(fps) if isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0 else None


def read_run(folder, model: FaceModel) -> Run:
    """The frames of the run in ``folder`` (``state/frame_KKKKK.npz``), checked against ``model``.

    The frames are those of ``frames.csv`` when the folder has one (a state file without its row
    is an unfinished frame), else every state file. Errors (one line): no such folder, no state
    files, a frame of ``frames.csv`` without its state file, a state file that is unreadable, lacks
    ``x`` or whose node count is not the model's (checked on the first file here, on every file as
    it is read).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FacesimError(f"{folder}: no such run folder" if not folder.exists() else f"{folder}: expected a run folder")
    states = {int(m.group(1)): p for p in (folder / "state").glob("frame_*.npz") if (m := _STATE.match(p.name))}
    if not states:
        raise FacesimError(f"{folder}: no state files (state/frame_KKKKK.npz); expected a folder written by facesim "
                           "simulate (or solve-mocap --write-meshes)")
    log = folder / "frames.csv"
    if log.is_file():
        frames = _listed_frames(log)
        missing = [int(k) for k in frames if int(k) not in states]
        if missing:
            raise FacesimError(f"{folder / 'state'}: missing state files of {len(missing)} frames listed in {log.name}, "
                               f"e.g. frame_{missing[0]:05d}.npz")
    else:
        frames = np.array(sorted(states), dtype=np.int64)
    if not len(frames):
        raise FacesimError(f"{log}: no frames")
    frames = np.unique(frames)

    def load(i: int):
        path = states[int(frames[i])]
        with open_npz(path, "a facesim state file (state/frame_KKKKK.npz)") as z:
            try:
                x = np.array(z["x"], dtype=np.float64)
                a = np.array(z["a"], dtype=np.float64) if "a" in z.files else np.zeros(model.n_muscles)
                ok = bool(z["converged"]) if "converged" in z.files else True
            except KeyError:
                raise FacesimError(f"{path}: field 'x' missing; expected a facesim state file") from None
            except Exception as exc:  # noqa: BLE001 (a corrupt member: zlib.error, BadZipFile, ValueError ...)
                raise FacesimError(f"{path}: unreadable state file ({type(exc).__name__})") from None
        if x.shape != model.X.shape:
            raise FacesimError(f"{path}: positions of {x.shape[0] if x.ndim == 2 else x.shape} nodes, the model has "
                               f"{model.n_nodes}; the folder holds a run of another model")
        if a.shape != (model.n_muscles,):
            raise FacesimError(f"{path}: {a.size} activations, the model has {model.n_muscles} muscles")
        return x, a, ok and bool(np.isfinite(x).all())

    load(0)   # a run of another model: say so before writing anything
    return Run(frames, load, _run_fps(folder), str(folder))


def _shown(model: FaceModel, run: Run):
    """Per frame ``(i, k, x, a, converged)`` with ``x, a`` those to show: the frame's own if it
    converged, else the last converged frame's (the rest pose and zero activations before one)."""
    held = (model.X, np.zeros(model.n_muscles))
    for i, k in enumerate(map(int, run.frames)):
        x, a, ok = run.load(i)
        if ok:
            held = (x, a)
        yield i, k, held[0], held[1], ok


def _fps(run: Run, fps: float | None) -> float:
    fps = fps if fps is not None else (run.fps or DEFAULT_FPS)
    if not (math.isfinite(fps) and fps > 0):
        raise FacesimError(f"fps: expected a frame rate > 0, got {fps}")
    return float(fps)


def bone_transforms(model: FaceModel, x) -> dict[str, np.ndarray]:
    """The rigid 4x4 transforms (mm) taking the rest positions of the cranium's and the jaw's
    attached nodes to ``x (n, 3)``: ``{"cranium": T, "jaw": T}`` (identity for a bone without nodes)."""
    from facesim.se3 import rigid_fit

    return {"cranium": rigid_fit(model.X[model.cranium_nodes], x[model.cranium_nodes]),
            "jaw": rigid_fit(model.X[model.jaw_nodes], x[model.jaw_nodes])}


def markers_of(model: FaceModel, run: Run) -> np.ndarray:
    """(F, n_markers, 3) mm marker positions of every frame of ``run``; NaN where it did not converge."""
    P = np.full((len(run), model.n_markers, 3), np.nan)
    for i in range(len(run)):
        x, _, ok = run.load(i)
        if ok:
            P[i] = model.marker_positions(x)
    return P


# ------------------------------------------------------------------ USD
def _pxr():
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, Vt
    except ImportError:
        raise FacesimError(_PXR_MISSING) from None
    return Gf, Sdf, Usd, UsdGeom, Vt


def _prim_name(name: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9_]", "_", name) or "surface"
    base = base if not base[0].isdigit() else f"_{base}"
    out, n = base, 1
    while out in taken:
        n += 1
        out = f"{base}_{n}"
    taken.add(out)
    return out


def write_usd(model: FaceModel, run: Run, path, fps: float | None = None, frame=None) -> Path:
    """Write ``run`` as a USD stage at ``path`` (``.usd`` / ``.usdc`` binary, ``.usda`` text) and
    return the path. See the module doc for the prims; ``fps`` (Hz) defaults to the run's;
    ``frame``: the :class:`~facesim.output_frame.OutputFrame` of the stage (None: facesim's, mm, y up).

    Prims: ``/Face`` (default prim) with ``skin`` (Mesh; ``facesim:node`` int[] the model node of
    each point), ``cranium`` and ``jaw`` (Xforms holding the model's bone and collider surfaces of
    that bone, a time-sampled ``xformOp:transform``), ``markers`` (Points; ``facesim:names``), and
    ``facesim:activations`` float[] per frame with ``facesim:muscles`` string[].
    """
    Gf, Sdf, Usd, UsdGeom, Vt = _pxr()
    path = require_suffix(path, USD_SUFFIXES, "a USD file name")
    fps = _fps(run, fps)
    frame = frame or FACESIM
    out = frame.points

    def vec3f(p):
        return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(p, dtype=np.float32))

    def extent(p):
        return vec3f(np.stack([p.min(axis=0), p.max(axis=0)]))

    def mesh(where: str, vertices, faces):
        m = UsdGeom.Mesh.Define(stage, where)
        m.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces, dtype=np.int32).ravel()))
        m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)   # triangles as they are, not a Catmull-Clark cage
        m.CreatePointsAttr(vec3f(vertices))
        m.CreateExtentAttr(extent(vertices))
        return m

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if frame.up_axis() == "Z" else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, frame.meters_per_unit)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(float(run.frames[0]))
    stage.SetEndTimeCode(float(run.frames[-1]))
    face = UsdGeom.Xform.Define(stage, "/Face")
    stage.SetDefaultPrim(face.GetPrim())

    nodes, inverse = np.unique(model.skin, return_inverse=True)
    skin = mesh("/Face/skin", out(model.X[nodes]), inverse.reshape(-1, 3))
    skin.GetPrim().CreateAttribute("facesim:node", Sdf.ValueTypeNames.IntArray).Set(
        Vt.IntArray.FromNumpy(nodes.astype(np.int32)))
    points, skin_extent = skin.GetPointsAttr(), skin.GetExtentAttr()
    ops, taken = {}, set()
    for bone in ("cranium", "jaw"):
        group = UsdGeom.Xform.Define(stage, f"/Face/{bone}")
        ops[bone] = group.AddTransformOp()
        for s in model.bones + model.colliders:
            if s.bone == bone:
                mesh(f"/Face/{bone}/{_prim_name(s.name, taken)}", out(s.vertices), s.faces)
    markers = UsdGeom.Points.Define(stage, "/Face/markers")
    markers.CreateWidthsAttr(Vt.FloatArray.FromNumpy(np.full(model.n_markers, 2.0 / frame.mm_per_unit,
                                                             dtype=np.float32)))   # 2 mm
    markers.GetPrim().CreateAttribute("facesim:names", Sdf.ValueTypeNames.StringArray).Set(list(model.markers.names))
    marker_points = markers.CreatePointsAttr()
    face.GetPrim().CreateAttribute("facesim:muscles", Sdf.ValueTypeNames.StringArray).Set(list(model.muscles.names))
    activations = face.GetPrim().CreateAttribute("facesim:activations", Sdf.ValueTypeNames.FloatArray)

    unconverged = []
    for _, k, x, a, ok in _shown(model, run):
        if not ok:
            unconverged.append(k)
        t = Usd.TimeCode(float(k))
        skin_x = out(x[nodes])
        points.Set(vec3f(skin_x), t)
        skin_extent.Set(extent(skin_x), t)
        for bone, T in bone_transforms(model, x).items():
            T = frame.transform(T)
            ops[bone].Set(Gf.Matrix4d(T.T.tolist()), t)   # USD transforms row vectors: p' = p M
        marker_points.Set(vec3f(out(model.marker_positions(x))), t)
        activations.Set(Vt.FloatArray.FromNumpy(a.astype(np.float32)), t)

    layer = stage.GetRootLayer()
    layer.customLayerData = {"facesim": {
        "version": facesim.__version__, "source": run.source, "fps": fps, "frames": len(run),
        "units": frame.units, "output_frame": frame.name, "unconverged_frames": Vt.IntArray(unconverged)}}

    def export(tmp: Path):
        try:
            ok = layer.Export(str(tmp))
        except Exception as exc:  # noqa: BLE001 (pxr raises Tf.ErrorException for file-system failures)
            raise OSError(f"USD could not write it ({' '.join(str(exc).split())[:200]})") from None
        if not ok:
            raise OSError("USD could not write it")

    return atomic_write(path, export)


# ------------------------------------------------------------------ ParaView
def tet_activation(model: FaceModel, a) -> tuple[np.ndarray, np.ndarray]:
    """Per tet, from activations ``a (n_muscles,)``: ``activation (n_tets,)`` = sum over the tet's
    muscle entries of fraction * a[muscle], and ``active_stress (n_tets,)`` MPa, the same weighted
    by the muscle's ``sigma_max``."""
    ms = model.muscles
    w = ms.fraction * np.asarray(a, dtype=np.float64)[ms.muscle]
    return (np.bincount(ms.tet, weights=w, minlength=model.n_tets),
            np.bincount(ms.tet, weights=w * ms.sigma_max[ms.muscle], minlength=model.n_tets))


def write_pvd(model: FaceModel, run: Run, path, fps: float | None = None, frame=None) -> Path:
    """Write ``run`` as the ParaView collection ``path`` (``.pvd``) of per-frame volumes
    ``<path without .pvd>/frame_KKKKK.vtu`` (and ``rest.vtu`` if the first frames did not
    converge); return the ``.pvd`` path. Arrays: see the module doc; field data ``frame``,
    ``converged`` and ``time`` (s). ``fps`` (Hz) defaults to the run's; ``frame``: the
    :class:`~facesim.output_frame.OutputFrame` of the points and displacements (None: facesim's, mm)."""
    import meshio

    path = require_suffix(path, (".pvd",), "a ParaView collection file name")
    fps = _fps(run, fps)
    frame = frame or FACESIM
    rest = frame.points(model.X)
    folder = path.with_suffix("")
    if folder.exists() and not folder.is_dir():
        raise FacesimError(f"{folder}: expected a folder for the .vtu files of {path.name}, found a file")
    dominant, _, _ = model.muscles.dominant(model.n_tets)
    names = {**{f"muscle:{n}": np.array([m], dtype=np.int32) for m, n in enumerate(model.muscles.names)},
             **{f"tissue:{t.name}": np.array([j], dtype=np.int32) for j, t in enumerate(model.tissues)}}

    def volume(name: str, k: int, x, a, ok: bool) -> str:
        activation, stress = tet_activation(model, a)
        cells = {"activation": [activation], "active_stress": [stress], "tissue": [model.tissue.astype(np.int32)],
                 "muscle": [dominant.astype(np.int32)]}
        field = {**names, "frame": np.array([k], dtype=np.int64), "converged": np.array([int(ok)], dtype=np.int32),
                 "time": np.array([k / fps])}
        points = frame.points(x)
        grid = meshio.Mesh(points, [("tetra", model.tets)], point_data={"displacement": points - rest},
                           cell_data=cells)

        def write(tmp: Path):
            meshio.write(tmp, grid, file_format="vtu")
            _add_field_data(tmp, field)

        atomic_write(folder / name, write)
        return f"{folder.name}/{name}"

    entries, unconverged, held = [], [], None
    for _, k, x, a, ok in _shown(model, run):
        if ok:
            held = volume(f"frame_{k:05d}.vtu", k, x, a, True)
        else:
            unconverged.append(k)
            if held is None:
                held = volume("rest.vtu", k, x, a, False)
        entries.append((k / fps, held))

    lines = ['<?xml version="1.0"?>',
             f"<!-- facesim {facesim.__version__}: {len(entries)} frames at {fps:g} fps; frames that did not converge "
             f"show the last converged one: {' '.join(map(str, unconverged)) or 'none'} -->",
             '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">', "  <Collection>"]
    lines += [f'    <DataSet timestep="{t:.9g}" group="" part="0" file={quoteattr(f)}/>' for t, f in entries]
    lines += ["  </Collection>", "</VTKFile>", ""]
    return atomic_write(path, lambda tmp: tmp.write_text("\n".join(lines)))


def _add_field_data(path: Path, field: dict) -> None:
    """Put ``field`` (name -> 1-d numeric array) into the VTU at ``path`` as ``<FieldData>`` of ascii
    arrays: meshio's VTU writer drops field data (5.3), its reader and VTK read it."""
    types = {"i": "Int", "u": "UInt", "f": "Float"}
    arrays = []
    for name, v in field.items():
        v = np.ravel(v)
        kind = f"{types[v.dtype.kind]}{8 * v.dtype.itemsize}"
        text = " ".join(repr(float(e)) if v.dtype.kind == "f" else str(int(e)) for e in v)
        arrays.append(f'<DataArray type="{kind}" Name={quoteattr(name)} NumberOfTuples="{len(v)}" '
                      f'format="ascii">{text}</DataArray>')
    xml = path.read_text()
    tag = "<UnstructuredGrid>"
    if xml.count(tag) != 1:
        raise OSError(f"unexpected VTU layout from meshio in {path.name}")
    path.write_text(xml.replace(tag, f"{tag}\n<FieldData>\n{chr(10).join(arrays)}\n</FieldData>"))


def read_pvd(path) -> list[tuple[float, Path]]:
    """The ``(timestep, .vtu path)`` entries of a ``.pvd`` collection, in file order."""
    import xml.etree.ElementTree as ET

    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise FacesimError(f"{path}: not a readable .pvd collection ({exc})") from None
    return [(float(d.get("timestep", "nan")), path.parent / d.get("file", "")) for d in root.iter("DataSet")]


# ------------------------------------------------------------------ C3D
def write_markers_c3d(path, frames, names, P, fps: float, units: str = "mm") -> Path:
    """Write marker trajectories ``P (F, N, 3)`` mm of the increasing ``frames (F,)`` to a C3D file
    at ``fps``, its numbers in ``units`` (:func:`facesim.mocap.io.write_c3d`; NaN = missing,
    residual -1). Frame numbers the sequence skips are written as frames whose markers are all
    missing."""
    from facesim.mocap.io import write_c3d

    frames = np.asarray(frames, dtype=np.int64)
    P = np.asarray(P, dtype=np.float64)
    _check_frames(frames, "markers")
    full = np.full((int(frames[-1] - frames[0]) + 1, *P.shape[1:]), np.nan)
    full[frames - frames[0]] = P
    return write_c3d(path, np.arange(frames[0], frames[-1] + 1), names, full, fps, units)


# ------------------------------------------------------------------ a run folder
def export_cache(folder, model: FaceModel, *, usd=None, pvd=None, c3d=None, fps: float | None = None,
                 output_frame="facesim") -> dict:
    """Write the caches asked for of the run in ``folder``: ``usd`` (path), ``pvd`` (path),
    ``c3d`` (path; from the run's ``markers.csv`` when it has one -- taken from the output frame
    the run recorded in ``report.json`` -- else the model's markers on the states). ``fps``
    defaults to the run's (``report.json``), else 30 Hz. ``output_frame``: ``"facesim"``,
    ``"input"`` (an imported model's input frame and units) or an
    :class:`~facesim.output_frame.OutputFrame`: the frame of all three. Returns ``{"frames",
    "unconverged_frames", "fps", "usd", "pvd", "c3d", "output_frame"}`` (paths as str or None)."""
    if usd is None and pvd is None and c3d is None:
        raise FacesimError("export-cache: nothing to do; give --usd OUT.usd, --pvd OUT.pvd and/or --c3d OUT.c3d")
    if usd is not None:
        require_suffix(usd, USD_SUFFIXES, "a USD file name")
        _pxr()   # before any work
    if pvd is not None:
        require_suffix(pvd, (".pvd",), "a ParaView collection file name")
    if c3d is not None:
        require_suffix(c3d, (".c3d",), "a C3D file name")
    frame = output_frame_of(model, output_frame)
    run = read_run(folder, model)
    fps = _fps(run, fps)
    done = {"frames": len(run), "fps": fps, "usd": None, "pvd": None, "c3d": None, "output_frame": frame.describe()}
    if usd is not None:
        done["usd"] = str(write_usd(model, run, usd, fps, frame))
    if pvd is not None:
        done["pvd"] = str(write_pvd(model, run, pvd, fps, frame))
    unconverged = [int(k) for i, k in enumerate(run.frames) if not run.load(i)[2]]
    if c3d is not None:
        csv_path = Path(folder) / "markers.csv"
        if csv_path.is_file():
            from facesim.mocap.io import read_markers_csv

            written = run_output_frame(model, _report(Path(folder)))   # the frame markers.csv is in
            data = read_markers_csv(csv_path, written.units)
            P = data.P if written.name == frame.name else \
                frame.points_mm(written.to_facesim(data.P / written.mm_per_unit))
            done["c3d"] = str(write_markers_c3d(c3d, data.frames, data.names, P, fps, frame.units))
        else:
            P = frame.points_mm(markers_of(model, run))
            done["c3d"] = str(write_markers_c3d(c3d, run.frames, model.markers.names, P, fps, frame.units))
    done["unconverged_frames"] = unconverged
    return done


__all__ = ["DEFAULT_FPS", "Run", "USD_SUFFIXES", "bone_transforms", "export_cache", "markers_of", "read_pvd",
           "read_run", "tet_activation", "write_markers_c3d", "write_pvd", "write_usd"]
