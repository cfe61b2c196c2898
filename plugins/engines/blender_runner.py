"""Trusted runner of the ``blender`` engine: runs one model-written bpy script to PNG frames.

It runs under the Blender virtual environment's Python (``import bpy``; no visphy import), inside
the sandbox, with the private work directory as its working directory::

    python -s -B blender_runner.py job.json

``job.json`` (written by ``plugins/engines/blender.py``) names the script, the output folder and
the render contract. The runner

1. resets Blender to factory settings with an empty scene and presets the clip: render fps =
   contract fps, ``frame_start = 1``, ``frame_end = n_frames``, resolution = contract size;
   seeds ``random`` (and numpy) with the contract seed; enables Python drivers;
2. executes the script as ``__main__`` (file name ``program.py``); handlers the script registers
   are wrapped so that an exception inside one is reported instead of silently swallowed;
3. forces the render settings (whatever the script set): render engine (Workbench by default,
   Cycles on the CPU with a fixed seed and no denoiser when configured), contract resolution at
   100 %, opaque film, no motion blur, no stamp, view transform "Standard" (sRGB colours map
   1:1 to pixels), no dither, 8-bit RGB PNG output into the work directory;
4. when the script uses Blender's rigid body world, steps every frame from the cache start to the
   last rendered frame once (Bullet only simulates frame by frame), then
5. renders exactly ``n_frames`` stills, one per contract frame, in increasing time order.

Frame ↔ time mapping (documented contract): contract frame k (0-based) shows time t_k = k / fps.
Blender frame ``scene.frame_start`` is t = 0 and time runs at the script's own
``scene.render.fps / fps_base``, so frame k renders Blender frame
``frame_start + k * script_fps / contract_fps``; when that is not an integer (the script changed
the fps) the fraction is rendered as a sub-frame (F-curves interpolate). The script's
``frame_end`` never shortens or lengthens the clip: after its last keyframe an animation holds.

Result: ``result.json`` with ``status`` ok | syntax_error | runtime_error | render_error |
sandbox_violation | infra_error, an ``error`` line, the user-code traceback and timings; the exit
status mirrors it (0 ok, 2 syntax, 3 runtime/render, 4 sandbox violation, 5 infra).
"""

from __future__ import annotations

import builtins
import errno
import json
import math
import os
import random
import sys
import time
import traceback

EXIT = {"ok": 0, "syntax_error": 2, "runtime_error": 3, "render_error": 3,
        "sandbox_violation": 4, "infra_error": 5}
ENGINES = {"workbench": "BLENDER_WORKBENCH", "cycles": "CYCLES", "eevee": "BLENDER_EEVEE"}
#: Materials whose viewport colour was never set still have Blender's default grey.
DEFAULT_DIFFUSE = (0.8, 0.8, 0.8, 1.0)


class HandlerError(Exception):
    """An exception raised inside a handler the script registered (Blender would swallow it)."""


def log(msg: str) -> None:
    print(f"[visphy-blender] {msg}", flush=True)


def write_result(path: str, status: str, **fields) -> int:
    data = {"status": status, **fields}
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(data, f, indent=1)
    os.replace(tmp, path)
    return EXIT[status]


def user_traceback(exc: BaseException, script_name: str) -> tuple[str, str]:
    """(one line "Type: message (program.py line N)", traceback limited to the script's frames)."""
    frames = [fr for fr in traceback.extract_tb(exc.__traceback__) if fr.filename == script_name]
    text = "".join(traceback.format_list(frames)) if frames else ""
    head = "".join(traceback.format_exception_only(type(exc), exc)).strip()
    line = f"{head} ({script_name} line {frames[-1].lineno})" if frames else head
    return line.replace("\n", " ")[:2000], ("Traceback (most recent call last):\n" + text + head)


def is_network_error(exc: BaseException) -> bool:
    import socket

    if isinstance(exc, socket.gaierror):
        return True
    return isinstance(exc, OSError) and exc.errno in (errno.ENETUNREACH, errno.EHOSTUNREACH,
                                                      errno.ECONNREFUSED)


# ------------------------------------------------------------------------------ setup


def set_fps(render, fps: float) -> None:
    """Integer fps exactly; otherwise fps = ceil(fps) with fps_base = ceil(fps) / fps."""
    whole = max(1, math.ceil(fps - 1e-9))
    render.fps = whole
    render.fps_base = 1.0 if abs(fps - whole) < 1e-9 else whole / fps


def preset_scene(bpy, job: dict) -> None:
    scene = bpy.context.scene
    set_fps(scene.render, job["fps"])
    scene.frame_start, scene.frame_end = 1, job["n_frames"]
    scene.frame_current = 1
    scene.render.resolution_x, scene.render.resolution_y = job["width"], job["height"]
    scene.render.resolution_percentage = 100
    scene.render.engine = ENGINES[job["render_engine"]]
    # a script that renders by itself writes inside the work dir, not to Blender's default /tmp/
    scene.render.filepath = os.path.join(os.getcwd(), "script_output", "")
    prefs = bpy.context.preferences
    prefs.filepaths.use_scripts_auto_execute = True  # Python drivers (the script is sandboxed)


def wrap_handlers(bpy, errors: list) -> None:
    """Make exceptions in the script's handlers visible (Blender prints and ignores them)."""
    handlers = bpy.app.handlers
    for name in ("frame_change_pre", "frame_change_post", "depsgraph_update_pre",
                 "depsgraph_update_post", "render_pre", "render_post", "render_init"):
        lst = getattr(handlers, name, None)
        if lst is None:
            continue
        for i, fn in enumerate(list(lst)):
            if getattr(fn, "_visphy_wrapped", False):
                continue

            def wrapped(*args, _fn=fn, _name=name):
                try:
                    return _fn(*args)
                except Exception as exc:  # noqa: BLE001 - reported by the runner
                    if not errors:
                        errors.append((_name, exc))
                    raise

            wrapped._visphy_wrapped = True
            if hasattr(fn, "_bpy_persistent"):
                wrapped._bpy_persistent = fn._bpy_persistent
            lst[i] = wrapped


def pick_scene(bpy):
    scene = bpy.context.scene
    if scene is None and len(bpy.data.scenes):
        scene = bpy.data.scenes[0]
    return scene


def ensure_camera(scene) -> str | None:
    """Use the scene camera; else the only / first camera object (by name). None = ok."""
    if scene.camera is not None and scene.camera.type == "CAMERA":
        return None
    cams = sorted((o for o in scene.objects if o.type == "CAMERA"), key=lambda o: o.name)
    if not cams:
        return "the script created no camera (add one and set bpy.context.scene.camera)"
    scene.camera = cams[0]
    log(f"scene.camera was not set: using camera object {cams[0].name!r}")
    return None


def sync_workbench_colours(bpy) -> int:
    """Workbench shows a material's viewport colour (``diffuse_color``); scripts written for
    Cycles/EEVEE set only the node colour. Copy an unlinked Principled/Emission/Diffuse colour
    into ``diffuse_color`` where that is still Blender's default grey. Returns how many changed."""
    changed = 0
    for mat in bpy.data.materials:
        if tuple(round(v, 6) for v in mat.diffuse_color) != DEFAULT_DIFFUSE or not mat.node_tree:
            continue
        colour = None
        for node in mat.node_tree.nodes:
            for socket_name in ("Base Color", "Color"):
                sock = node.inputs.get(socket_name) if hasattr(node, "inputs") else None
                if sock is not None and not sock.is_linked and node.type in (
                        "BSDF_PRINCIPLED", "EMISSION", "BSDF_DIFFUSE", "BSDF_TOON",
                        "SUBSURFACE_SCATTERING", "BSDF_GLOSSY"):
                    colour = tuple(sock.default_value)
                    break
            if colour is not None:
                break
        if colour is not None:
            mat.diffuse_color = colour[:3] + (mat.diffuse_color[3],)
            changed += 1
    return changed


def force_render_settings(bpy, scene, job: dict) -> None:
    r = scene.render
    r.engine = ENGINES[job["render_engine"]]
    r.resolution_x, r.resolution_y = job["width"], job["height"]
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.use_border = False
    r.use_crop_to_border = False
    r.film_transparent = False
    r.use_motion_blur = False
    if hasattr(r, "use_stamp"):
        r.use_stamp = False
    r.dither_intensity = 0.0
    r.use_multiview = False
    threads = int(job.get("threads") or 0)
    r.threads_mode = "FIXED" if threads > 0 else "AUTO"
    if threads > 0:
        r.threads = threads
    vs = scene.view_settings
    if job.get("view_transform"):
        scene.display_settings.display_device = "sRGB"
        vs.view_transform = job["view_transform"]
        vs.look = "None"
        vs.exposure, vs.gamma = 0.0, 1.0
        vs.use_curve_mapping = False
    img = r.image_settings
    if hasattr(img, "media_type"):  # Blender 5.0: image / multilayer / video
        img.media_type = "IMAGE"
    img.file_format = "PNG"
    img.color_mode = "RGB"
    img.color_depth = "8"
    img.compression = 15
    if job["render_engine"] == "cycles":
        c = scene.cycles
        c.device = "CPU"
        c.samples = int(job.get("samples", 16))
        c.preview_samples = c.samples
        c.seed = int(job.get("seed", 0))
        c.use_animated_seed = False
        c.use_denoising = bool(job.get("denoise", False))
        c.use_adaptive_sampling = False
        c.time_limit = 0.0
    if job["render_engine"] == "eevee" and hasattr(scene, "eevee"):
        scene.eevee.taa_render_samples = int(job.get("samples", 16))
    if job["render_engine"] == "workbench":
        n = sync_workbench_colours(bpy)
        if n:
            log(f"Workbench: copied the node colour of {n} material(s) into diffuse_color")


def preroll_rigid_bodies(scene, last_frame: float) -> int:
    """Blender's rigid body world only simulates frame by frame (a jump leaves the cache empty):
    step every frame from its cache start to the last rendered frame once, in order, so the
    point cache holds the whole simulation before any frame is rendered. Returns frames stepped."""
    rbw = getattr(scene, "rigidbody_world", None)
    if rbw is None or not rbw.enabled:
        return 0
    last = math.ceil(last_frame)
    cache = rbw.point_cache
    if cache.frame_end < last:
        cache.frame_end = last
    start = min(cache.frame_start, scene.frame_start)
    for f in range(start, last + 1):
        scene.frame_set(f)
    return last + 1 - start


def frame_for(k: int, job: dict, scene) -> tuple[int, float]:
    """Blender (frame, subframe) for contract frame k: frame_start + k * script_fps / fps."""
    script_fps = scene.render.fps / scene.render.fps_base
    f = scene.frame_start + k * script_fps / job["fps"]
    whole = math.floor(f + 1e-9)
    sub = f - whole
    return whole, (0.0 if sub < 1e-9 else sub)


# ------------------------------------------------------------------------------- main


# long: one Blender job in order (import, compile, reset, run, simulate, render), each step
# returning its own result; it runs in Blender's Python, testable only where Blender is installed
def main() -> int:
    job_path = sys.argv[1] if len(sys.argv) > 1 else "job.json"
    with open(job_path) as f:
        job = json.load(f)
    result_path = job.get("result", "result.json")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    try:
        import bpy
    except Exception as exc:  # noqa: BLE001
        return write_result(result_path, "infra_error", error=f"cannot import bpy: {exc}")
    timings["import_s"] = time.perf_counter() - t0
    info = {"bpy_version": bpy.app.version_string}

    script_name = job["script"]
    with open(script_name, encoding="utf-8") as f:
        source = f.read()
    try:
        code = compile(source, script_name, "exec")
    except (SyntaxError, ValueError) as exc:
        line, tb = user_traceback(exc, script_name)
        if isinstance(exc, SyntaxError):
            line = f"SyntaxError: {exc.msg} ({script_name} line {exc.lineno})"
        return write_result(result_path, "syntax_error", error=line, traceback=tb, **info)

    t1 = time.perf_counter()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    preset_scene(bpy, job)
    random.seed(job.get("seed", 0))
    try:
        import numpy

        numpy.random.seed(job.get("seed", 0))
    except Exception:  # noqa: BLE001 - numpy is optional for the script
        pass
    timings["reset_s"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    handler_errors: list = []
    old_argv = sys.argv
    sys.argv = [script_name]
    try:
        exec(code, {"__name__": "__main__", "__file__": script_name, "__builtins__": builtins})
    except SystemExit as exc:
        if exc.code not in (None, 0):
            return write_result(result_path, "runtime_error",
                                error=f"the script called sys.exit({exc.code!r})", **info)
        log("the script called sys.exit(0): rendering what it built")
    except BaseException as exc:  # noqa: BLE001 - any exception is the script's failure
        line, tb = user_traceback(exc, script_name)
        status = "sandbox_violation" if is_network_error(exc) else "runtime_error"
        if status == "sandbox_violation":
            line = f"network access attempted: {line}"
        return write_result(result_path, status, error=line, traceback=tb, **info)
    finally:
        sys.argv = old_argv
    timings["script_s"] = time.perf_counter() - t2
    wrap_handlers(bpy, handler_errors)

    scene = pick_scene(bpy)
    if scene is None:
        return write_result(result_path, "render_error", error="the script left no scene", **info)
    problem = ensure_camera(scene)
    if problem:
        return write_result(result_path, "render_error", error=problem, **info)
    try:
        force_render_settings(bpy, scene, job)
    except Exception as exc:  # noqa: BLE001
        return write_result(result_path, "render_error",
                            error=f"could not apply the render settings: {exc}", **info)

    out_dir = job["out_dir"]
    os.makedirs(out_dir, exist_ok=True)
    n = job["n_frames"]
    frame_map = [frame_for(k, job, scene) for k in range(n)]
    log(f"bpy {info['bpy_version']}: {n} frames at {job['width']}x{job['height']}, engine "
        f"{scene.render.engine}, Blender frames {frame_map[0]} .. {frame_map[-1]}")
    t3 = time.perf_counter()
    try:
        stepped = preroll_rigid_bodies(scene, frame_map[-1][0] + frame_map[-1][1])
        if handler_errors:
            raise HandlerError()
    except BaseException as exc:  # noqa: BLE001
        exc = handler_errors[0][1] if handler_errors else exc
        line, tb = user_traceback(exc, script_name)
        return write_result(result_path, "runtime_error", error=f"simulating the rigid body "
                            f"world failed: {line}", traceback=tb, **info)
    if stepped:
        log(f"rigid body world: simulated {stepped} frames before rendering")
    timings["simulate_s"] = time.perf_counter() - t3
    t3 = time.perf_counter()
    for k, (frame, sub) in enumerate(frame_map):
        try:
            scene.frame_set(frame, subframe=sub)
            if handler_errors:
                raise HandlerError()
            scene.render.filepath = os.path.join(os.getcwd(), out_dir, f"frame_{k:05d}.png")
            bpy.ops.render.render(write_still=True, scene=scene.name)
            if handler_errors:
                raise HandlerError()
        except BaseException as err:  # noqa: BLE001
            if handler_errors:
                name, exc = handler_errors[0]
                prefix = f"in a {name} handler at frame {k}: "
            else:
                exc, prefix = err, f"rendering frame {k} failed: "
            line, tb = user_traceback(exc, script_name)
            line = prefix + line
            status = "sandbox_violation" if is_network_error(exc) else "runtime_error"
            return write_result(result_path, status, error=line, traceback=tb,
                                frames_rendered=k, **info)
    timings["render_s"] = time.perf_counter() - t3
    timings["total_s"] = time.perf_counter() - t0
    return write_result(result_path, "ok", frames_rendered=n, frame_map=frame_map,
                        render_engine=scene.render.engine, timings=timings, **info)


if __name__ == "__main__":
    sys.exit(main())
