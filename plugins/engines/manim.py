"""Engine ``manim``: a Python program using Manim Community Edition (scripted animation, no
physics engine), run in a sandboxed child process (`visphy_core.sandbox.process`).

How a program becomes frames:

* **Extraction / validation** (host): the reply's ```python block; it must compile (else
  ``syntax_error`` with the line) and define a class ``GeneratedScene`` deriving from a Manim
  scene (else ``no_code``).
* **Render** (sandbox): the program and the trusted runner (`manim_runner.py`, copied next to
  it) go into a private work dir, and the runner is started with the host's own interpreter
  (``sys.executable``, so the same Manim) under `run_sandboxed` (bubblewrap): uid 65534, fresh
  network/PID/IPC/UTS/mount namespaces, a read-only view of only ``/usr``, fonts and this
  interpreter's venv and base installation, the work dir as the only writable place, scrubbed
  environment, rlimits, a disk quota, wall-clock limit = ``contract.timeout_s``.
  The runner presets Manim's configuration (``pixel_width/height`` = contract size,
  ``frame_rate`` = contract fps, white background, Manim's default camera frame of 14.22 × 8
  units, Cairo renderer, caching off, no media files: ``dry_run``), seeds ``random``/``numpy``
  with ``contract.seed``, imports the program and renders ``GeneratedScene``, capturing in
  memory the frames the clip needs.
* **Frame rule**: the program's own settings are honoured. Its camera frame is the
  ``config.frame_width × config.frame_height`` it leaves after import (Manim's default 14.22 × 8
  when it sets none; changing only ``pixel_width/height`` makes the height follow that pixel
  aspect ratio, as in Manim), its ``frame_rate`` and background colour are its own. The frame is
  never cropped: it is rendered whole at the largest pixel size of its aspect ratio that fits
  the clip and centred on a clip-sized canvas of the background colour (letterboxing; the row
  gets the flag ``canvas_resized`` and the log says how). A frame with the clip's aspect ratio
  fills the clip exactly, as before.
* **Timing**: Manim emits frame *i* of a scene at scene time *i / frame_rate* (every
  ``play``/``wait`` of duration *d* emits about d·rate frames - ⌈d·rate⌉ for an animation,
  ⌊d·rate⌋ for a static ``wait`` - starting at its own start state). Clip frame *k* shows the
  last frame emitted at or before t = k / fps (frame *k* itself when the program keeps the
  clip's frame rate): a scene longer than ``n_frames / fps`` is **truncated** (rendering stops
  as soon as the clip is complete), a shorter one **holds its last frame** to the end. A scene
  that plays no animation at all emits no frame: ``blank_output``.
* **Determinism**: Cairo rasterises deterministically, the seeds are fixed, ``PYTHONHASHSEED=0``
  and BLAS runs single-threaded, so the same program gives byte-identical frames.

Failure classes: syntax error → ``syntax_error``; any exception while importing or rendering →
``runtime_error`` (exception type, message and program line in ``error``; the frames captured
before a runtime error are kept as ``RenderResult.partial_frames`` with the flag
``partial_clip``); wall-clock or CPU limit → ``timeout``; address-space, file-size, work-dir
disk quota or process-count limit → ``resource_limit``; no frame or only one flat colour →
``blank_output``; a sandbox that cannot start (bubblewrap missing, namespaces refused and no
explicit opt-out) → ``infra_error`` with the reason. The isolation the program ran under is
``RenderResult.isolation`` and the first line of ``RenderResult.logs`` (``sandbox: ...``).

Frames cross the sandbox boundary as one raw file (``frames.rgb``: no codec, no header, the
runner writes clip-sized RGB frames); the program runs in the runner's process and could rewrite
it, so the host reads it with `visphy_core.infra.video.read_untrusted_raw_frames`: no symbolic link,
a regular file, at most ``n_frames`` clip-sized frames (a larger file is refused by its size,
unread: ``runtime_error`` "frame output refused: frames.rgb is N bytes, more than the clip's ...
refused unread"), straight into one clip-sized array. Reading it counts against the scene's
wall-clock limit (one deadline: sandbox start + ``timeout_s``); past it the render is a
``timeout``.

Configuration (``conf/engine/manim.yaml``, schema `ManimConfig`): ``timeout_s``, ``memory_mb``,
``file_size_mb``, ``disk_mb``, ``keep_workdir``.
"""

from __future__ import annotations

import ast
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

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
from visphy_core.api.extract import extract_code, extract_spec
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.media import DeadlineExceeded, FrameRejected
from visphy_core.api.sandbox import (
    Limits,
    ProcessResult,
    describe_limit,
    python_ro_paths,
    read_untrusted,
    run_sandboxed,
)
from visphy_core.api.scene import Scene
from visphy_core.api.settings import cfg_get
from visphy_core.api.spec import replay_payload

log = logging.getLogger(__name__)

TEMPLATES = Path(__file__).with_name("templates")

INSTRUCTIONS = """
Write one Python program for Manim Community Edition (manim 0.18-0.22, `from manim import *`)
that defines `class GeneratedScene(Scene)` with a `construct(self)` method; visphy renders that
class itself (do not call render() or use the command line). There is no physics engine: script
the motion yourself, e.g. by integrating positions and velocities with a fixed time step in
Python and moving mobjects with updaters, ValueTrackers or one `self.wait(1 / config.frame_rate)`
per video frame. Use only numpy, math and manim; there is no network and no LaTeX, so write
text with `Text(...)`, never `MathTex` or `Tex`.
The camera is fixed, with a white background; config.pixel_width x config.pixel_height is the
video size (W x H) and config.frame_rate its frame rate. The camera frame is config.frame_width x
config.frame_height units with the origin at its centre: Manim's default 14.22 x 8 units (16:9)
unless your program sets them. visphy shows that whole frame, scaled uniformly to fit the video
and centred, with background-coloured bars where its aspect ratio differs from the video's. To
make the frame match the video exactly, set right after the import
`config.frame_height = 8.0` and `config.frame_width = 8.0 * config.pixel_width /
config.pixel_height`; an image pixel (px, py) measured from the bottom-left corner with y up is
then the point ((px - W/2) * 8 / H, (py - H/2) * 8 / H, 0). Draw flat shapes (Circle, Rectangle,
Polygon, ...) with fill_opacity=1 and stroke_width=0 in the colours of the images. Scene time t
is video time: the frame shown at t = k / fps is video frame k; the scene should last the whole
clip.
""".strip()

INSTRUCTIONS_3D = INSTRUCTIONS + """
For a 3D scene derive GeneratedScene from ThreeDScene and set a fixed camera orientation with
self.set_camera_orientation(...) that matches the view in the images.
"""


# ------------------------------------------------------------------------------ trusted runner
#: The trusted part of every render (`manim_runner.py`), copied into the work dir next to
#: ``program.py`` and run there. It reads ``job.json``, writes ``frames.rgb`` (raw uint8 RGB,
#: frame after frame) + ``result.json``, or ``error.json`` and exits 3. Everything it writes is
#: treated as untrusted by the host (the program runs in the same process).
RUNNER = Path(__file__).resolve().with_name("manim_runner.py")


def manim_available() -> tuple[bool, str]:
    """(True, version) when Manim CE imports in this interpreter, else (False, reason).

    The import is quiet: Manim logs "Reading config file: ..." at INFO while it imports, before
    its own handler exists, so the record reaches the root logger (a run's console, inside the
    progress bars). Here its logger neither propagates nor prints below WARNING, and what the
    import writes goes to this module's debug log. A render's own Manim output stays in its
    render log (the sandboxed runner's stdout and stderr)."""
    if "manim" in sys.modules:
        manim = sys.modules["manim"]
        return True, getattr(manim, "__version__", "?")
    import contextlib
    import io

    manim_log = logging.getLogger("manim")
    caught = _Records()
    manim_log.addHandler(caught)
    manim_log.propagate = False
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            import manim
    except Exception as exc:  # noqa: BLE001
        return False, (f"manim is not importable ({type(exc).__name__}: {exc}); run "
                       "scripts/setup_manim.sh")
    finally:
        manim_log.removeHandler(caught)
        manim_log.propagate = False
        manim_log.setLevel(max(manim_log.getEffectiveLevel(), logging.WARNING))
        for line in [*caught.lines, *out.getvalue().splitlines()]:
            log.debug("manim import: %s", line)
    return True, getattr(manim, "__version__", "?")


class _Records(logging.Handler):
    """Keeps the messages of the records it is handed."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


@dataclass
class ManimConfig(EngineConfig):
    """``conf/engine/manim.yaml``: EngineConfig plus the sandbox limits of one render (ranges in
    the field metadata are checked before any work)."""

    name: str = "manim"
    timeout_s: float = field(default=60.0, metadata={"min": 1, "max": 3600})
    memory_mb: int = field(default=4096, metadata={"min": 256})   # address space (RLIMIT_AS)
    file_size_mb: int = field(default=512, metadata={"min": 1})   # largest file written
    disk_mb: int = field(default=1024, metadata={"min": 16})      # work dir quota
    keep_workdir: bool = False                                   # keep work dirs (debugging)


class ManimEngine(Engine):
    name = "manim"
    language = "python"
    version = "2"  # 2: the program's own frame, letterboxed; flags; partial clips
    supports_3d = False  # programs may use ThreeDScene; the reference program is 2D only

    #: Sandbox limits besides the wall clock; the engine config (`ManimConfig`: ``memory_mb``,
    #: ``file_size_mb``, ``disk_mb``, ``keep_workdir``) overrides them.
    memory_mb = 4096
    file_size_mb = 512
    disk_mb = 1024

    def instructions(self, dim: str) -> str:
        return INSTRUCTIONS_3D if dim == "3d" else INSTRUCTIONS

    def cache_identity(self) -> str:
        """Manim's version changes anti-aliasing details, so it is part of every cache key."""
        ok, version = manim_available()
        return f"{self.name}@{self.version}+manim-{version if ok else 'missing'}"

    # ------------------------------------------------------------------ extract / validate
    def extract(self, text: str) -> Program:
        source = extract_code(text, ("python", "py", "python3"))
        return Program(language=self.language, source=source, spec=extract_spec(text))

    def validate(self, program: Program) -> None:
        try:
            tree = ast.parse(program.source, filename="program.py")
            compile(tree, "program.py", "exec")
        except SyntaxError as exc:
            raise ProgramRejected(FailureClass.SYNTAX_ERROR,
                                  f"SyntaxError: {exc.msg} (line {exc.lineno})") from None
        except ValueError as exc:  # e.g. null bytes in the source
            raise ProgramRejected(FailureClass.SYNTAX_ERROR, f"invalid source: {exc}") from None
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef) and node.name == "GeneratedScene":
                bases = [b.attr if isinstance(b, ast.Attribute) else getattr(b, "id", "")
                         for b in node.bases]
                if any(name.endswith("Scene") for name in bases):
                    return
        raise ProgramRejected(FailureClass.NO_CODE,
                              "the program defines no class GeneratedScene(Scene)")

    # ------------------------------------------------------------------ render
    def render(self, program: Program, contract: RenderContract) -> RenderResult:
        start = time.monotonic()
        keep = bool(cfg_get(self.cfg, "keep_workdir", False))
        work = Path(tempfile.mkdtemp(prefix="visphy-manim-"))
        try:
            (work / "program.py").write_text(program.source)
            shutil.copy(RUNNER, work / RUNNER.name)
            (work / "job.json").write_text(json.dumps({
                "width": contract.width, "height": contract.height, "fps": contract.fps,
                "n_frames": contract.n_frames, "seed": contract.seed}))
            frames_mb = (contract.n_frames * contract.width * contract.height * 3 >> 20) + 64
            limits = Limits(wall_s=contract.timeout_s, cpu_s=contract.timeout_s + 5,
                            memory_mb=int(cfg_get(self.cfg, "memory_mb", self.memory_mb)),
                            file_size_mb=max(int(cfg_get(self.cfg, "file_size_mb",
                                                          self.file_size_mb)), frames_mb),
                            disk_mb=max(int(cfg_get(self.cfg, "disk_mb", self.disk_mb)),
                                        frames_mb + 64))
            env = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                   "PYTHONDONTWRITEBYTECODE": "1", "PYTHONUNBUFFERED": "1",
                   "XDG_CACHE_HOME": str(work / ".cache")}
            # one wall-clock deadline for the sandbox and for reading its frames on the host
            deadline = time.monotonic() + float(contract.timeout_s)
            res = run_sandboxed([sys.executable, "-s", "-B", RUNNER.name], work, limits,
                                env_extra=env, ro_paths=python_ro_paths(sys.executable))
            result = self._classify(res, work, contract, limits, deadline)
            result.isolation = res.isolation
            result.logs.insert(0, f"sandbox: {res.isolation}; exit {res.returncode}; "
                                  f"{res.wall_s:.2f} s")
            if keep:
                result.logs.append(f"work dir kept: {work}")
        finally:
            if not keep:
                shutil.rmtree(work, ignore_errors=True)
        # defence in depth: no configured secret value leaves the engine
        result.error = redact(result.error)
        result.logs = [redact(line) for line in result.logs]
        result.wall_s = time.monotonic() - start
        return result

    @staticmethod
    def _classify(res: ProcessResult, work: Path, contract: RenderContract,
                  limits: Limits, deadline: float | None = None) -> RenderResult:
        logs = [f"[stdout] {line}" for line in res.stdout.splitlines()[-40:]]
        logs += [f"[stderr] {line}" for line in res.stderr.splitlines()[-60:]]
        result = RenderResult(frames=None, logs=logs, wall_s=res.wall_s)
        error = _read_json(work / "error.json")
        what = _describe(error) if isinstance(error, dict) else _last_line(res.stderr)
        if res.refused or (res.returncode is None and res.limit_hit is None):
            result.failure = FailureClass.INFRA_ERROR
            result.error = _last_line(res.stderr)
        elif res.timed_out:
            result.failure = FailureClass.TIMEOUT
            result.error = f"no result within {contract.timeout_s:g} s (infinite loop?)"
        elif res.limit_hit == "cpu":
            result.failure = FailureClass.TIMEOUT
            result.error = f"CPU time limit ({limits.cpu_s:g} s) exceeded"
        elif (limit := describe_limit(res.limit_hit, limits, what)) is not None:
            result.failure, result.error = FailureClass.RESOURCE_LIMIT, limit
        elif res.returncode != 0 and isinstance(error, dict):
            result.failure = (FailureClass.SYNTAX_ERROR if error.get("kind") == "syntax"
                              else FailureClass.INFRA_ERROR if error.get("kind") == "import_manim"
                              else FailureClass.RUNTIME_ERROR)
            result.error = _describe(error)
            count = error.get("frames")
            if (result.failure is FailureClass.RUNTIME_ERROR and isinstance(count, int)
                    and 0 < count < contract.n_frames):
                partial = _read_partial(work, contract, count, deadline, result)
                if partial is not None:
                    result.partial_frames = partial
                    result.flag(RenderFlag.PARTIAL_CLIP)
                    result.logs.append(f"partial clip: {count} of {contract.n_frames} frames "
                                       "were captured before the error")
            if result.failure is FailureClass.RUNTIME_ERROR:
                _note_frame(result, error, contract)
        elif res.returncode != 0:
            result.failure = FailureClass.RUNTIME_ERROR
            if res.returncode < 0:
                result.error = f"the program was killed by signal {-res.returncode}"
            else:
                result.error = f"exit status {res.returncode}: {_last_line(res.stderr)}"
        else:
            try:
                frames, problem = _read_frames(work, contract, deadline)
            except DeadlineExceeded as exc:
                frames, problem = None, None
                result.failure = FailureClass.TIMEOUT
                result.error = (f"no result within {contract.timeout_s:g} s: reading the frames "
                                f"on the host went past the limit ({exc})")
            if result.failure is not None:
                pass
            elif problem:
                result.failure, result.error = FailureClass.RUNTIME_ERROR, problem
            elif frames is None:
                result.failure = FailureClass.BLANK_OUTPUT
                result.error = ("the scene emitted no frame (no self.play / self.wait in "
                                "construct)")
            elif classify_frames(frames) is FailureClass.BLANK_OUTPUT:
                result.failure = FailureClass.BLANK_OUTPUT
                result.error = "every frame is one flat colour"
            else:
                result.frames = frames
            _note_frame(result, _read_json(work / "result.json"), contract)
        return result

    # ------------------------------------------------------------------ reference program
    def program_from_spec(self, scene: Scene) -> Program:
        spec = scene.spec
        if scene.dim == "3d":
            raise NotImplementedError(
                f"{scene.scene_id}: the manim engine has no reference program for 3D scenes "
                "(Manim's Cairo renderer draws 3D only approximately); use the threejs engine "
                "for 3D oracles")
        payload = replay_payload(scene)
        source = (TEMPLATES / "manim_replay_2d.py.tmpl").read_text()
        source = source.replace("__SCENE_JSON__",
                                repr(json.dumps(payload, separators=(",", ":"))))
        return Program(language=self.language, source=source, spec=spec)

    def native_program_from_spec(self, scene: Scene) -> Program:
        """The same replay drawn as Manim mobjects (Circle, Rectangle, Polygon) by Cairo, with
        its anti-aliasing (`visphy_plugins.engines.native`); 2D only."""
        if scene.dim == "3d":
            raise NotImplementedError(
                f"{scene.scene_id}: the manim engine has no reference program for 3D scenes; "
                "use the threejs engine for 3D oracles")
        from visphy_plugins.engines.native import native_payload

        source = (TEMPLATES / "manim_native_2d.py.tmpl").read_text()
        source = source.replace("__SCENE_JSON__", repr(json.dumps(native_payload(scene),
                                                                  separators=(",", ":"))))
        return Program(language=self.language, source=source, spec=scene.spec)


# ------------------------------------------------------------------------------ helpers
_read_untrusted = read_untrusted


def _read_json(path: Path, max_bytes: int = 1 << 20):
    data = _read_untrusted(path, max_bytes)
    if data is None:
        return None
    try:
        return json.loads(data.decode("utf-8", "replace"))
    except ValueError:
        return None


def _last_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1][:500] if lines else "no output"


def _describe(error: dict) -> str:
    kind, message = str(error.get("type", "Error")), str(error.get("message", ""))[:1500]
    line = error.get("line")
    text = f"{kind}: {message}" + (f" (program line {line})" if isinstance(line, int) else "")
    low = (kind + message).lower()
    if "latex" in low or "mathtex" in low or "dvisvgm" in low:
        text += " - LaTeX is not installed: use Text(...) instead of MathTex/Tex"
    return text


def _note_frame(result: RenderResult, meta, contract: RenderContract) -> None:
    """Log the program's camera frame and how it was fitted; flag a letterboxed one."""
    info = meta.get("frame") if isinstance(meta, dict) else None
    if not isinstance(info, dict):
        return
    try:
        fw, fh = float(info["width"]), float(info["height"])
        pw, ph = (int(v) for v in info["pixels"])
        x0, y0 = (int(v) for v in info["offset"])
        rate = float(info["frame_rate"])
    except (KeyError, TypeError, ValueError):
        return
    line = f"frame: {fw:.6g} x {fh:.6g} units at {rate:g} fps"
    if (pw, ph) != (contract.width, contract.height):
        result.flag(RenderFlag.CANVAS_RESIZED)
        line += (f"; letterboxed into the {contract.width}x{contract.height} clip: {pw}x{ph} px "
                 f"at ({x0}, {y0}), background-coloured bars")
    else:
        line += f", filling the {contract.width}x{contract.height} clip"
    if rate != contract.fps:
        line += f"; clip frame k shows the last frame emitted by t = k / {contract.fps:g}"
    result.logs.append(line)


def _read_raw(work: Path, contract: RenderContract, max_frames: int,
              deadline: float | None) -> np.ndarray:
    """``frames.rgb`` through the shared untrusted-frame reader (no link, a regular file, at
    most ``max_frames`` clip-sized frames by its size, ``deadline``)."""
    from visphy_core.api.media import read_untrusted_raw_frames

    return read_untrusted_raw_frames(work / "frames.rgb", contract.width, contract.height,
                                     max_frames, deadline)


def _read_partial(work: Path, contract: RenderContract, count: int,
                  deadline: float | None = None,
                  result: RenderResult | None = None) -> np.ndarray | None:
    """The ``count`` clip frames the runner wrote before a runtime error, or None (the log of
    ``result`` says why when the file was refused or the deadline passed)."""
    try:
        frames = _read_raw(work, contract, count, deadline)
    except (FrameRejected, DeadlineExceeded) as exc:
        if result is not None and "is missing" not in str(exc):
            result.logs.append(f"partial clip dropped: {exc}")
        return None
    return frames if len(frames) == count else None


def _read_frames(work: Path, contract: RenderContract, deadline: float | None = None
                 ) -> tuple[np.ndarray | None, str | None]:
    """Frames the runner wrote (held to ``n_frames``), None when it wrote none, or a problem;
    `DeadlineExceeded` when reading them passes ``deadline``."""
    meta = _read_json(work / "result.json")
    no_result = ("the runner wrote no usable result (the program ended the process early, or "
                 "replaced its output files?)")
    if not isinstance(meta, dict) or not os.path.lexists(work / "frames.rgb"):
        return None, no_result
    try:
        frames = _read_raw(work, contract, contract.n_frames, deadline)
    except FrameRejected as exc:
        return None, (f"frame output refused: {exc} (the runner writes at most the clip's "
                      "frames: the program rewrote its output files?)")
    count = len(frames)
    if count != meta.get("frames"):
        return None, (f"corrupt frame output ({count} frames in frames.rgb, result says "
                      f"{meta.get('frames')!r})")
    if count == 0:
        return None, None
    if count < contract.n_frames:  # the scene ended early: hold its last frame
        hold = np.repeat(frames[-1:], contract.n_frames - count, axis=0)
        frames = np.concatenate([frames, hold])
    return frames, None  # writable, independent of any buffer


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="engine", name="schema_manim", node=ManimConfig)


@hookimpl
def visphy_register_engines(register):
    register("manim", ManimEngine)
