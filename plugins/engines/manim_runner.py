"""Trusted runner of the ``manim`` engine: renders one model-written Manim program to raw frames.

It runs under the host's own interpreter (the same Manim; no visphy import), inside the sandbox,
with the private work directory as its working directory::

    python -s -B manim_runner.py

next to ``program.py`` (the model's program) and ``job.json`` (the render contract, written by
``plugins/engines/manim.py``, which copies this file into the work directory). The runner

1. seeds ``random`` and numpy with the contract seed and presets Manim's configuration: pixel
   size = the clip (``config.pixel_width/height``), ``frame_rate`` = the clip's fps, white
   background, and Manim's own default camera frame (``config.frame_width × frame_height`` =
   14.22 × 8 units, 16:9), plus the settings that keep a render private and deterministic (Cairo
   renderer, caching off, ``dry_run``: no media files, no preview);
2. imports the program (file ``program.py``, module ``generated_program``) and reads back the
   configuration it leaves: **the program's frame** is its ``config.frame_width ×
   config.frame_height`` (when it changed only ``pixel_width/height`` the height follows its
   pixel aspect ratio, as Manim's camera does), its ``frame_rate`` and its background;
3. **letterboxes** that frame into the clip: the camera renders exactly the program's frame at
   the largest pixel size of the same aspect ratio that fits the clip (uniform scale), and each
   frame is pasted centred on a clip-sized canvas of the camera's background colour (the bars).
   A frame with the clip's aspect ratio fills the clip: nothing is cropped, nothing is padded;
4. renders ``GeneratedScene`` and keeps in memory the frames the contract needs: Manim emits
   frame *i* at scene time *i / frame_rate*; clip frame *k* (t = k / fps) is the last frame
   emitted at or before t, so a program that changes ``frame_rate`` keeps its timing. Rendering
   stops once the clip has ``n_frames`` frames; a shorter scene is held by the host.

Output: ``frames.rgb`` (raw uint8 RGB, clip size, frame after frame) and ``result.json`` (frame
count, Manim version, the frame and how it was fitted), exit 0; or ``error.json`` and exit 3 (an
exception while importing or rendering; the frames captured before a runtime error are still in
``frames.rgb``, their count in ``error.json``). The program runs in this process: the host treats
every file here as untrusted.
"""

import json
import math
import os
import random
import sys
import traceback

PROGRAM = os.path.abspath("program.py")
#: A frame's aspect ratio equal to the clip's within this relative tolerance fills the clip.
ASPECT_TOLERANCE = 1e-9


class Enough(BaseException):
    """Raised once the clip has all its frames (a BaseException: `except Exception` in the
    program does not swallow it)."""


class Capture:
    """The clip frames kept from what the renderer emits."""

    def __init__(self, job):
        self.width, self.height = job["width"], job["height"]
        self.fps, self.n_frames = job["fps"], job["n_frames"]
        self.frames = []       # clip frames, RGB uint8, clip size
        self.emitted = 0       # frames the renderer emitted so far
        self.rate = self.fps   # the program's frame rate
        self.fit = (self.width, self.height)
        self.offset = (0, 0)
        self.frame = None      # the program's frame (width, height) in units, once known

    def info(self):
        """The program's frame and how it was fitted (for the host's log)."""
        if self.frame is None:
            return None
        return {"width": self.frame[0], "height": self.frame[1], "pixels": list(self.fit),
                "offset": list(self.offset), "frame_rate": self.rate, "emitted": self.emitted}

    def source_index(self, k):
        """Index of the emitted frame that clip frame ``k`` shows (last one at or before t_k)."""
        if self.rate == self.fps:
            return k
        return int(math.floor(k * self.rate / self.fps + 1e-9))

    def add(self, renderer, frame, num_frames):
        rgb = None
        for _ in range(int(num_frames)):
            index = self.emitted
            self.emitted += 1
            while (len(self.frames) < self.n_frames
                   and self.source_index(len(self.frames)) <= index):
                if rgb is None:
                    rgb = self.to_clip(renderer, frame)
                self.frames.append(rgb)
            if len(self.frames) >= self.n_frames:
                raise Enough()

    def to_clip(self, renderer, frame):
        import numpy as np
        from PIL import Image

        frame = _over_white(np.asarray(frame))
        fit_w, fit_h = self.fit
        if frame.shape[:2] != (fit_h, fit_w):
            # the program resized its camera while rendering: fit what it gave
            img = Image.fromarray(frame)
            scale = min(fit_w / img.width, fit_h / img.height)
            new = (max(1, round(img.width * scale)), max(1, round(img.height * scale)))
            frame = np.asarray(img.resize(new, Image.Resampling.BILINEAR))
        h, w = frame.shape[:2]
        if (w, h) == (self.width, self.height):
            return frame
        canvas = np.empty((self.height, self.width, 3), dtype=np.uint8)
        canvas[:, :] = _bar_colour(renderer)
        x0, y0 = (self.width - w) // 2, (self.height - h) // 2
        canvas[y0:y0 + h, x0:x0 + w] = frame
        return canvas

    def write(self):
        with open("frames.rgb", "wb") as out:
            for frame in self.frames:
                out.write(frame.tobytes())


def _over_white(frame):
    """RGBA (Manim's pixel array) composited over white, as contiguous RGB uint8."""
    import numpy as np

    if frame.ndim == 3 and frame.shape[2] == 4:
        if not np.all(frame[..., 3] == 255):
            alpha = frame[..., 3:4].astype(np.float32) / 255.0
            rgb = frame[..., :3].astype(np.float32) * alpha + 255.0 * (1.0 - alpha)
            frame = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
        else:
            frame = frame[..., :3]
    return np.ascontiguousarray(frame, dtype=np.uint8)


def _bar_colour(renderer):
    """The camera's background colour (over white): the colour of the letterbox bars."""
    try:
        background = renderer.camera.background
        return _over_white(background[:1, :1])[0, 0]
    except Exception:  # noqa: BLE001 - a camera without a background array: white
        return (255, 255, 255)


def program_frame(cfg, preset):
    """(width, height) in units of the frame the program configured, or a problem (str)."""
    fw, fh = cfg.frame_width, cfg.frame_height
    pw, ph = cfg.pixel_width, cfg.pixel_height
    try:
        fw, fh, pw, ph = float(fw), float(fh), float(pw), float(ph)
    except (TypeError, ValueError):
        return f"the frame configuration is not numeric ({fw!r} x {fh!r})"
    if not all(math.isfinite(v) and v > 0 for v in (fw, fh, pw, ph)):
        return (f"invalid frame configuration: frame {fw!r} x {fh!r} units, "
                f"{pw!r} x {ph!r} pixels")
    if (pw, ph) != (preset["pixel_width"], preset["pixel_height"]) and fh == preset["frame_height"]:
        fh = fw * ph / pw  # Manim's camera: the width stays, the height follows the pixels
    return fw, fh


def fit_pixels(fw, fh, width, height):
    """Pixel size of the program's frame scaled uniformly to fit the clip, and its offset."""
    clip_aspect, aspect = width / height, fw / fh
    if abs(aspect - clip_aspect) <= ASPECT_TOLERANCE * clip_aspect:
        return (width, height), (0, 0)
    if aspect > clip_aspect:
        fit = (width, max(1, min(height, round(width / aspect))))
    else:
        fit = (max(1, min(width, round(height * aspect))), height)
    return fit, ((width - fit[0]) // 2, (height - fit[1]) // 2)


def fail(kind, exc=None, message=None, capture=None):
    info = {"kind": kind, "type": type(exc).__name__ if exc is not None else kind,
            "message": message if message is not None else str(exc), "line": None,
            "frames": 0}
    if exc is not None:
        if isinstance(exc, SyntaxError) and exc.filename == PROGRAM:
            info["line"] = exc.lineno
        for frame in traceback.extract_tb(exc.__traceback__):
            if frame.filename == PROGRAM:
                info["line"] = frame.lineno
        traceback.print_exception(type(exc), exc, exc.__traceback__)
    if capture is not None:
        info["frame"] = capture.info()
    if capture is not None and capture.frames and kind == "runtime":
        try:  # the frames before the error: kept by the host as a partial clip
            capture.write()
            info["frames"] = len(capture.frames)
        except Exception:  # noqa: BLE001
            info["frames"] = 0
    with open("error.json", "w") as f:
        json.dump(info, f)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(3)


def main():
    with open("job.json") as f:
        job = json.load(f)
    W, H, FPS, SEED = job["width"], job["height"], job["fps"], job["seed"]
    capture = Capture(job)

    random.seed(SEED)
    # Manim's messages while it imports ("Reading config file: ...") go to stderr, which the
    # host keeps in the render log; nothing of the sandbox reaches the host's terminal.
    import logging
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(name)s %(levelname)s: %(message)s")
    try:
        import numpy as np
        np.random.seed(SEED)
        import manim
        from manim import config, tempconfig
        from manim.renderer.cairo_renderer import CairoRenderer
    except BaseException as exc:  # noqa: BLE001
        fail("import_manim", exc)

    # Settings no program changes: a private, deterministic render without media files.
    fixed = {
        "transparent": False, "renderer": "cairo", "disable_caching": True, "dry_run": True,
        "write_to_movie": False, "save_last_frame": False, "preview": False,
        "show_in_file_browser": False, "progress_bar": "none", "verbosity": "WARNING",
        "media_dir": os.path.abspath("media"), "seed": SEED, "from_animation_number": 0,
        "upto_animation_number": -1,
    }
    if "ffmpeg_executable" in config:
        # Manim < 0.19 refuses to start without an ffmpeg binary even when, as here, nothing is
        # encoded (dry run, frames are taken in memory); it only checks the path is executable.
        import shutil
        fixed["ffmpeg_executable"] = shutil.which("ffmpeg") or shutil.which("true") or "/bin/true"
    # What the program starts from (it may change these): the clip's pixels and fps, a white
    # background and Manim's own default camera frame.
    preset = {"pixel_width": W, "pixel_height": H, "frame_rate": FPS,
              "frame_width": config.frame_width, "frame_height": config.frame_height,
              "background_color": "#FFFFFF", "background_opacity": 1.0}

    def add_frame(self, frame, num_frames=1):
        """Replaces CairoRenderer.add_frame: keep clip frames in memory instead of encoding."""
        if self.skip_animations:
            return
        self.time += num_frames / self.camera.frame_rate
        capture.add(self, frame, num_frames)

    CairoRenderer.add_frame = add_frame

    with tempconfig({**preset, **fixed}):
        try:
            import importlib.util
            spec = importlib.util.spec_from_file_location("generated_program", PROGRAM)
            module = importlib.util.module_from_spec(spec)
            sys.modules["generated_program"] = module
            spec.loader.exec_module(module)
        except SyntaxError as exc:
            fail("syntax", exc)
        except BaseException as exc:  # noqa: BLE001
            fail("runtime", exc)
        frame = program_frame(config, preset)
        if isinstance(frame, str):
            fail("runtime", message=frame)
        fw, fh = frame
        rate = config.frame_rate
        if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
            fail("runtime", message=f"invalid config.frame_rate {rate!r}")
        capture.rate = float(rate)
        capture.fit, capture.offset = fit_pixels(fw, fh, W, H)
        capture.frame = (fw, fh)
        config.update({k: v for k, v in fixed.items() if k in config})
        config.update({"pixel_width": capture.fit[0], "pixel_height": capture.fit[1],
                       "frame_width": fw, "frame_height": fh, "frame_rate": capture.rate})
        cls = getattr(module, "GeneratedScene", None)
        if not (isinstance(cls, type) and issubclass(cls, manim.Scene)):
            fail("no_scene", message="the program defines no class GeneratedScene(Scene)")
        random.seed(SEED)
        np.random.seed(SEED)
        try:
            scene = cls()
            scene.render()
        except Enough:
            pass
        except SyntaxError as exc:
            fail("syntax", exc)
        except BaseException as exc:  # noqa: BLE001
            fail("runtime", exc, capture=capture)

    capture.write()
    with open("result.json", "w") as f:
        json.dump({"frames": len(capture.frames), "width": W, "height": H,
                   "manim": getattr(manim, "__version__", "?"),
                   "frame": capture.info()}, f)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


if __name__ == "__main__":
    main()
