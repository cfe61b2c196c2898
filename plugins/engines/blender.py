"""Engine ``blender``: a bpy (Blender as a Python module) script, rendered to frames in a sandbox.

bpy needs numpy < 2 and Python 3.11 (cp311 wheels, ~940 MB), which conflicts with the main
environment, so Blender lives in its own virtual environment (``scripts/setup_blender.sh``) and
every scene runs as one subprocess of that environment's interpreter:

    <blender venv>/bin/python -s -B blender_runner.py job.json

inside a private work directory, through `visphy_core.sandbox.process.run_sandboxed`
(bubblewrap: uid 65534, fresh network/PID/IPC/UTS/mount namespaces, a read-only view of ``/usr``
and of only the Blender venv and its base Python, the work dir as the only writable place,
scrubbed environment, rlimits, a work-dir disk quota, wall-clock kill of the whole PID
namespace). The isolation is recorded in ``RenderResult.isolation`` and the render log; memory,
file-size, disk and process-count hits are ``resource_limit``, wall/CPU ``timeout``, a sandbox
that cannot start ``infra_error`` with the reason. Files the script leaves in the work dir are
read without following symlinks and with size limits.

Frames cross the sandbox boundary as files the script could have rewritten (an ``atexit``
handler runs after the runner wrote ``result.json``), so the host reads them only through
`visphy_core.infra.video.read_untrusted_frames`: exactly the names ``frame_00000.png`` ..
``frame_{n_frames-1}.png`` (other files are ignored), each a regular file (no symbolic link)
of bounded size whose PNG header must say exactly the contract's width × height **before** it is
decoded. The runner always renders at the contract size, so a frame of another size is not fitted
but refused: ``runtime_error`` "frame output refused: frame_00000.png is 10000x10000 px, not the
clip's 64x64: refused before decoding (...)". Reading the frames on the host counts against the
scene's wall-clock limit (one deadline: sandbox start + ``contract.timeout_s``); past it the
render is a ``timeout``.

The trusted runner
(`blender_runner.py`, copied into the work directory) resets Blender to an empty factory scene,
runs the model's script, forces the render settings (engine, contract size at 100 %, colour
management "Standard", fixed seeds, PNG output) and renders exactly ``n_frames`` stills; the frame
<-> time mapping is documented in that file: contract frame k is Blender frame
``frame_start + k * script_fps / fps`` (frame_start is t = 0; sub-frames when the script changed
its fps).

Interpreter lookup: ``python`` in the engine config, else ``$VISPHY_BLENDER_PYTHON``, else
``${VISPHY_BLENDER_VENV:-~/.cache/visphy/blender-venv}/bin/python``; when none exists the render
is an ``infra_error`` ("Blender venv missing: run scripts/setup_blender.sh").

Extraction and validation: the longest ```python block (an unlabelled block counts when it
imports bpy); ``compile()`` failing is ``syntax_error``; valid Python that never imports bpy is
``wrong_language`` (it is a program, but for another library: matplotlib, pygame, manim...), an
empty block is ``no_code``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import stat
import tempfile
import time
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any, Optional

import numpy as np

from visphy_core.api.calls import redact
from visphy_core.api.config_schema import EngineConfig
from visphy_core.api.engine import (
    Engine,
    FailureClass,
    Program,
    ProgramRejected,
    RenderContract,
    RenderFlag,
    RenderResult,
    classify_frames,
)
from visphy_core.api.extract import extract_code, extract_spec, fenced_blocks
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.media import DeadlineExceeded, FrameRejected
from visphy_core.api.scene import Scene
from visphy_core.api.settings import cfg_get
from visphy_core.api.spec import replay_payload

HERE = Path(__file__).resolve().parent
RUNNER = HERE / "blender_runner.py"
TEMPLATE = HERE / "templates" / "blender_replay.py.tmpl"
NATIVE_TEMPLATE_2D = HERE / "templates" / "blender_native_2d.py.tmpl"
SETUP_HINT = "Blender venv missing: run scripts/setup_blender.sh"
RENDER_ENGINES = ("workbench", "cycles", "eevee")
SCRIPT_NAME = "program.py"

_IMPORTS_BPY = re.compile(r"^[ \t]*(?:import[ \t]+(?:[\w.]+[ \t]*,[ \t]*)*bpy\b|from[ \t]+bpy\b)",
                          re.M)


class RenderEngine(str, Enum):
    """``engine.render_engine``: OmegaConf checks the value against these names at compose
    time."""

    workbench = "workbench"   # ≈0.04 s/frame
    cycles = "cycles"         # CPU path tracer, fixed seed
    eevee = "eevee"           # slow without a GPU


@dataclass
class BlenderConfig(EngineConfig):
    """``conf/engine/blender.yaml``: EngineConfig plus Blender's render settings (ranges in the
    field metadata are checked before any work)."""

    name: str = "blender"
    timeout_s: float = field(default=120.0, metadata={"min": 1, "max": 3600})
    render_engine: RenderEngine = RenderEngine.workbench
    samples: int = field(default=16, metadata={"min": 1, "max": 4096})  # Cycles/EEVEE samples
    denoise: bool = False              # Cycles denoiser (off: frames depend on the seed only)
    threads: int = field(default=0, metadata={"min": 0, "max": 1024})  # 0 = all cores
    view_transform: str = "Standard"   # colour management; "Standard": sRGB colours 1:1
    memory_mb: int = field(default=4096, metadata={"min": 256})  # address space (RLIMIT_AS)
    disk_mb: int = field(default=2048, metadata={"min": 16})     # work dir quota
    python: Optional[str] = None       # Blender venv interpreter (default: see module doc)
    keep_workdir: bool = False         # keep the per-scene work directory (debugging)


def _engine_name(cfg: Any) -> str:
    """``render_engine`` as a lower-case string (the config holds a `RenderEngine`)."""
    value = cfg_get(cfg, "render_engine", "workbench")
    if isinstance(value, Enum):
        value = value.value
    return str(value).lower()


def default_venv() -> Path:
    return Path(os.environ.get("VISPHY_BLENDER_VENV")
                or Path.home() / ".cache" / "visphy" / "blender-venv")


def find_blender_python(cfg: Any = None) -> Path | None:
    """The Blender venv's interpreter, or None when it is not installed."""
    candidates = [cfg_get(cfg, "python", None), os.environ.get("VISPHY_BLENDER_PYTHON"),
                  str(default_venv() / "bin" / "python")]
    for cand in candidates:
        if cand and Path(cand).is_file() and os.access(cand, os.X_OK):
            return Path(cand)
    return None


def bpy_version(python: Path | None) -> str | None:
    """bpy's version from the venv's dist-info (no Blender start-up)."""
    if python is None:
        return None
    venv = python.parent.parent
    for dist in sorted(venv.glob("lib/python3*/site-packages/bpy-*.dist-info")):
        return dist.name[len("bpy-"):-len(".dist-info")]
    return None


INSTRUCTIONS_COMMON = """
Write one Python script for Blender 5.0 (`import bpy`) in a single ```python block. visphy runs it
headless in a fresh, empty factory scene and then renders the animation itself with a fixed
renderer: do not call bpy.ops.render, do not set scene.render.engine, do not save or load .blend
files, do not read or write files, no network. Build the scene with bpy: create every object,
material and the camera yourself and set `bpy.context.scene.camera`; keep the camera fixed. Give
each material its colour with `mat.diffuse_color = (r, g, b, 1)` (linear RGB: the renderer shows
this viewport colour) and make the background with
`scene.world = bpy.data.worlds.new("w"); scene.world.color = (1, 1, 1)`.
Animate the whole clip, either with Blender's rigid body world (`bpy.ops.rigidbody.world_add()`,
`bpy.ops.rigidbody.object_add()` on the active object, `obj.rigid_body.type/mass/friction/
restitution`; visphy simulates it frame by frame from frame_start before rendering) or by
simulating the motion in plain Python with a fixed time step and inserting keyframes with
`obj.keyframe_insert("location", frame=f)` (and the rotation) for every frame. The scene arrives
with `scene.frame_start = 1` (= time 0), `scene.frame_end` = the clip's last frame and
`scene.render.fps` = the clip's frame rate: read them instead of hard-coding them; frame f shows
time (f - frame_start) / fps. A `bpy.app.handlers.frame_change_pre` handler is allowed only if it
sets the state as a pure function of `scene.frame_current` (it may run several times per frame).
Blender 5.0 notes: `Action.fcurves` no longer exists (for linear keyframes set
`bpy.context.preferences.edit.keyframe_new_interpolation_type = 'LINEAR'` before inserting
them); numpy and the standard library are available.
""".strip()

INSTRUCTIONS_2D = INSTRUCTIONS_COMMON + """

2D scene: work in pixel units (1 Blender unit = 1 pixel of the video), x to the right, y up, origin
at the bottom-left corner of the frame, all bodies in the plane z = 0 (use z only to order
overlapping shapes). Use an orthographic camera (`cam.data.type = 'ORTHO'`, `ortho_scale` = the
frame width) at (width / 2, height / 2, 100) looking down -z, flat unlit colours
(`scene.display.shading.light = 'FLAT'`, `scene.display.shading.color_type = 'MATERIAL'`,
`scene.display.render_aa = 'OFF'`), a white world, and flat meshes (discs, rectangles, polygons)
that match the first frame's layout and colours. Motion stays in the plane: no z motion, rotation
only about z. Gravity points along -y here: with the rigid body world set `scene.gravity` to
(0, -g, 0) in pixels / s^2 and keep every body in the plane (e.g. a generic rigid body constraint
locking z translation and x/y rotation), or keyframe your own 2D simulation.
""".rstrip()

INSTRUCTIONS_3D = INSTRUCTIONS_COMMON + """

3D scene: Blender's world is z-up (x right, y into the screen, z up). Use a fixed perspective
camera matching the view in the images, a large grey floor plane, a white world, shaded solid
colours (`scene.display.shading.light = 'STUDIO'`), and rigid bodies (spheres, boxes, ramps,
containers, planks) whose full 3D motion, including rotation, comes from the rigid body world
(gravity -z by default) or from your own fixed-step simulation.
""".rstrip()


class BlenderEngine(Engine):
    name = "blender"
    language = "python"
    version = "3"  # 2: partial_clip; 3: frames of another size are refused, not fitted
    supports_3d = True

    # ------------------------------------------------------------------ prompt & programs
    def instructions(self, dim: str) -> str:
        return INSTRUCTIONS_3D if dim == "3d" else INSTRUCTIONS_2D

    def extract(self, text: str) -> Program:
        try:
            source = extract_code(text, ("python", "py", "python3", "bpy"))
        except ProgramRejected as exc:
            if exc.failure is not FailureClass.WRONG_LANGUAGE:
                raise
            # an unlabelled block that imports bpy is still the program
            blocks, _ = fenced_blocks(text)
            bare = [b for lang, b in blocks if lang == "" and _IMPORTS_BPY.search(b)]
            if not bare:
                raise
            source = max(bare, key=len)
        return Program(language=self.language, source=source, spec=extract_spec(text))

    def validate(self, program: Program) -> None:
        source = program.source
        if not source.strip():
            raise ProgramRejected(FailureClass.NO_CODE, "the python block is empty")
        try:
            compile(source, SCRIPT_NAME, "exec")
        except SyntaxError as exc:
            raise ProgramRejected(FailureClass.SYNTAX_ERROR,
                                  f"SyntaxError: {exc.msg} ({SCRIPT_NAME} line {exc.lineno})")
        except ValueError as exc:  # e.g. null bytes in the source
            raise ProgramRejected(FailureClass.SYNTAX_ERROR, f"{SCRIPT_NAME}: {exc}")
        if not _IMPORTS_BPY.search(source):
            raise ProgramRejected(FailureClass.WRONG_LANGUAGE,
                                  "the Python program never imports bpy (a Blender script "
                                  "must `import bpy`)")

    def program_from_spec(self, scene: Scene) -> Program:
        spec = scene.spec
        payload = replay_payload(scene)
        source = TEMPLATE.read_text().replace(
            "__SCENE_JSON__", repr(json.dumps(payload, separators=(",", ":"))))
        return Program(language=self.language, source=source, spec=spec)

    def native_program_from_spec(self, scene: Scene) -> Program:
        """2D: flat meshes (a 64-vertex disc on the true radius, rectangles, n-gons) with a
        Principled-BSDF material, under Workbench's default anti-aliasing
        (`visphy_plugins.engines.native`). 3D: the exact reference program, which already draws
        meshes with Blender's renderer (anti-aliased as the ground truth is)."""
        if scene.dim == "3d":
            return self.program_from_spec(scene)
        from visphy_plugins.engines.native import native_payload

        source = NATIVE_TEMPLATE_2D.read_text().replace(
            "__SCENE_JSON__", repr(json.dumps(native_payload(scene), separators=(",", ":"))))
        return Program(language=self.language, source=source, spec=scene.spec)

    def cache_identity(self) -> str:
        parts = [f"{self.name}@{self.version}", _engine_name(self.cfg)]
        if _engine_name(self.cfg) != "workbench":
            parts += [f"s{cfg_get(self.cfg, 'samples', 16)}",
                      f"dn{int(cfg_get(self.cfg, 'denoise', 0))}"]
        parts += [str(cfg_get(self.cfg, "view_transform", "Standard")),
                  f"bpy{bpy_version(find_blender_python(self.cfg)) or '?'}"]
        return ":".join(parts)

    # ------------------------------------------------------------------------- render
    def render(self, program: Program, contract: RenderContract) -> RenderResult:
        start = time.perf_counter()
        python = find_blender_python(self.cfg)
        if python is None:
            return RenderResult(frames=None, failure=FailureClass.INFRA_ERROR, error=SETUP_HINT)
        render_engine = _engine_name(self.cfg)
        if render_engine not in RENDER_ENGINES:
            return RenderResult(frames=None, failure=FailureClass.INFRA_ERROR,
                                error=f"engine.render_engine={render_engine!r}; valid: "
                                      f"{', '.join(RENDER_ENGINES)}")
        from visphy_core.api.sandbox import Limits, python_ro_paths, run_sandboxed

        workdir = Path(tempfile.mkdtemp(prefix="visphy-blender-"))
        try:
            shutil.copy(RUNNER, workdir / RUNNER.name)
            (workdir / SCRIPT_NAME).write_text(program.source, encoding="utf-8")
            job = {"script": SCRIPT_NAME, "out_dir": "frames", "result": "result.json",
                   "fps": contract.fps, "n_frames": contract.n_frames,
                   "width": contract.width, "height": contract.height,
                   "render_engine": render_engine, "samples": int(cfg_get(self.cfg, "samples", 16)),
                   "denoise": bool(cfg_get(self.cfg, "denoise", False)),
                   "threads": int(cfg_get(self.cfg, "threads", 0)),
                   "view_transform": cfg_get(self.cfg, "view_transform", "Standard"),
                   "seed": int(contract.seed), "dim": contract.dim}
            (workdir / "job.json").write_text(json.dumps(job, indent=1))
            cores = int(cfg_get(self.cfg, "threads", 0)) or (os.cpu_count() or 1)
            # PNG frames are at most ~4 bytes per pixel (+ headers); keep room for them
            frames_mb = (contract.n_frames * contract.width * contract.height * 4 >> 20) + 64
            limits = Limits(
                wall_s=float(contract.timeout_s),
                cpu_s=float(contract.timeout_s) * max(1, cores),
                memory_mb=int(cfg_get(self.cfg, "memory_mb", 4096)),
                disk_mb=max(int(cfg_get(self.cfg, "disk_mb", 2048)), frames_mb + 64),
                max_files=max(20000, contract.n_frames + 1000))
            # HOME and TMPDIR are the work dir (run_sandboxed); PYTHONHASHSEED is fixed there
            env = {"PYTHONNOUSERSITE": "1", "PYTHONDONTWRITEBYTECODE": "1"}
            # one wall-clock deadline for the sandbox and for reading its frames on the host
            deadline = time.monotonic() + float(contract.timeout_s)
            proc = run_sandboxed([str(python), "-s", "-B", RUNNER.name, "job.json"], workdir,
                                 limits, env_extra=env, ro_paths=python_ro_paths(python))
            result = self._collect(proc, workdir, contract, limits, deadline)
            result.isolation = proc.isolation
            result.logs.insert(0, f"sandbox: {proc.isolation}; exit {proc.returncode}; "
                                  f"{proc.wall_s:.2f} s")
        finally:
            if not cfg_get(self.cfg, "keep_workdir", False):
                shutil.rmtree(workdir, ignore_errors=True)
        # defence in depth: no configured secret value leaves the engine
        result.error = redact(result.error)
        result.logs = [redact(line) for line in result.logs]
        result.wall_s = time.perf_counter() - start
        return result

    def _collect(self, proc: Any, workdir: Path, contract: RenderContract,
                 limits: Any, deadline: float | None = None) -> RenderResult:
        logs = [line for line in _lines(proc.stdout) + _lines(proc.stderr)
                if not _noise(line)][-200:]
        result = RenderResult(frames=None, logs=logs)
        from visphy_core.api.sandbox import describe_limit, limit_from_text, read_untrusted

        raw = read_untrusted(workdir / "result.json", 4 << 20)
        try:
            info = json.loads(raw.decode("utf-8", "replace")) if raw is not None else {}
        except ValueError:
            info = {}
        if not isinstance(info, dict):
            info = {}
        if info.get("traceback"):
            result.logs.append(str(info["traceback"])[:20000])
        status = info.get("status")
        frame_files = _frame_files(workdir / "frames", contract.n_frames)
        fail = FailureClass
        detail = str(info["error"])[:1500] if info.get("error") else ""
        hit = proc.limit_hit
        if hit is None and status in ("runtime_error", "render_error"):
            # the runner caught the script's exception itself (MemoryError, EFBIG, EAGAIN)
            hit = limit_from_text(str(info.get("error") or "")[:2000])
        if proc.refused or (proc.returncode is None and proc.limit_hit is None):
            result.failure = fail.INFRA_ERROR
            result.error = f"could not start Blender: {' '.join(_lines(proc.stderr))[-500:]}"
        elif proc.timed_out or proc.limit_hit in ("wall", "cpu"):
            which = "CPU time" if proc.limit_hit == "cpu" else "time"
            result.failure = fail.TIMEOUT
            result.error = (f"no result within the {which} limit of {contract.timeout_s:g} s "
                            f"({len(frame_files)}/{contract.n_frames} frames rendered; "
                            "infinite loop or too heavy a scene?)")
        elif (limit := describe_limit(hit, limits, detail)) is not None:
            result.failure, result.error = fail.RESOURCE_LIMIT, limit
        elif status == "syntax_error":
            result.failure, result.error = fail.SYNTAX_ERROR, info.get("error")
        elif status in ("runtime_error", "render_error"):
            result.failure, result.error = fail.RUNTIME_ERROR, info.get("error")
            _keep_partial(result, info.get("frames_rendered"), frame_files, contract, deadline)
        elif status == "sandbox_violation":
            result.failure, result.error = fail.SANDBOX_VIOLATION, info.get("error")
        elif status == "infra_error":
            result.failure, result.error = fail.INFRA_ERROR, info.get("error")
        elif status != "ok":
            rc = proc.returncode
            tail = " | ".join(logs[-3:])[-500:]
            how = f"killed by signal {-rc}" if rc is not None and rc < 0 else f"exit status {rc}"
            result.failure = fail.RUNTIME_ERROR
            result.error = f"Blender stopped without a result ({how}): {tail}"
        elif not frame_files:
            result.failure, result.error = fail.BLANK_OUTPUT, "Blender rendered no frames"
        if result.failure is not None:
            return result
        if len(frame_files) != contract.n_frames:
            result.failure = fail.BLANK_OUTPUT
            result.error = f"{len(frame_files)} frames rendered, {contract.n_frames} expected"
            return result
        try:
            frames = _read_frames(frame_files, contract, deadline)
        except DeadlineExceeded as exc:
            result.failure = fail.TIMEOUT
            result.error = (f"no result within the time limit of {contract.timeout_s:g} s: "
                            f"reading the rendered frames on the host went past it ({exc})")
            return result
        except FrameRejected as exc:
            result.failure = fail.RUNTIME_ERROR
            result.error = f"frame output refused: {exc} {TAMPERED}"
            return result
        if classify_frames(frames) is FailureClass.BLANK_OUTPUT:
            result.failure, result.error = fail.BLANK_OUTPUT, "every frame is one flat colour"
            return result
        result.frames = frames
        timings = info.get("timings") or {}
        if isinstance(timings, dict) and timings:
            result.logs.append("blender timings: " + ", ".join(
                f"{k} {v:.2f}" if isinstance(v, (int, float)) else f"{k} ?"
                for k, v in list(timings.items())[:20]))
        return result


#: Appended to a refused frame's reason: the trusted runner writes nothing else.
TAMPERED = ("(the runner writes every frame as an 8-bit PNG at the clip's size: the program "
            "changed the render settings or rewrote the frame files)")


def _frame_files(frames_dir: Path, n_frames: int) -> list[Path]:
    """The frames the runner writes, ``frame_00000.png`` .. ``frame_{n_frames-1}.png``, that
    exist, in order: only when ``frames`` is a real directory (not a link the script planted);
    any other file there is ignored (never listed, never read). What each entry is (a link, a
    FIFO, a huge file) is judged by `read_untrusted_frames`, which refuses it with the reason."""
    try:
        if not stat.S_ISDIR(os.lstat(frames_dir).st_mode):
            return []
    except OSError:
        return []
    out = []
    for k in range(n_frames):
        p = frames_dir / f"frame_{k:05d}.png"
        try:
            os.lstat(p)
        except OSError:
            continue
        out.append(p)
    return out


def _lines(text: Any) -> list[str]:
    if not text:
        return []
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    return [line for line in str(text).splitlines() if line.strip()]


_NOISE = re.compile(r"\|\s*Saved: '|^Saved: '|^EGL Error|^\s*Time: \d")


def _noise(line: str) -> bool:
    """Blender's per-frame "Saved:" chatter and headless-GL warnings."""
    return _NOISE.search(line) is not None


def _read_frames(paths: list[Path], contract: RenderContract,
                 deadline: float | None = None) -> np.ndarray:
    """The PNG frames, each exactly the clip's size (the runner renders nothing else): read by
    the shared untrusted-frame reader (header before decoding, no links, size caps, at most
    ``n_frames``, ``deadline``); raises `FrameRejected` or `DeadlineExceeded`."""
    from visphy_core.api.media import read_untrusted_frames

    return read_untrusted_frames(paths, contract.width, contract.height, contract.n_frames,
                                 deadline)


def _keep_partial(result: RenderResult, rendered: Any, frame_files: list[Path],
                  contract: RenderContract, deadline: float | None = None) -> None:
    """After a runtime error at frame k: frames 0..k-1 (rendered before it) as the partial clip,
    read like a whole clip; a refused frame or the deadline drops it (the failure stays the
    program's ``runtime_error``; the log says why there is no partial clip)."""
    if not isinstance(rendered, int) or not 0 < rendered < contract.n_frames:
        return
    names = [f"frame_{k:05d}.png" for k in range(rendered)]
    if [p.name for p in frame_files[:rendered]] != names:
        return
    try:
        result.partial_frames = _read_frames(frame_files[:rendered], contract, deadline)
    except DeadlineExceeded as exc:
        result.logs.append(f"partial clip dropped: reading it went past the time limit of "
                           f"{contract.timeout_s:g} s ({exc})")
        return
    except FrameRejected as exc:
        result.logs.append(f"partial clip refused: {exc} {TAMPERED}")
        return
    result.flag(RenderFlag.PARTIAL_CLIP)
    result.logs.append(f"partial clip: {rendered} of {contract.n_frames} frames were rendered "
                       "before the error")


# ------------------------------------------------------------------ reference program payload




@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="engine", name="schema_blender", node=BlenderConfig)


@hookimpl
def visphy_register_engines(register):
    register("blender", BlenderEngine)
