"""Engine `manim`: extraction, validation, rendering contract, determinism, failure classes and the
reference program against ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from visphy_core.api.engine import FailureClass, Program, ProgramRejected, RenderContract

pytestmark = pytest.mark.manim

try:
    import manim  # noqa: F401
except Exception as exc:  # noqa: BLE001
    pytest.skip(f"Manim CE is not importable ({type(exc).__name__}: {exc}); run "
                "scripts/setup_manim.sh", allow_module_level=True)

from visphy_plugins.engines.manim import INSTRUCTIONS, ManimEngine  # noqa: E402

HEADER = "from manim import *\n\nclass GeneratedScene(Scene):\n    def construct(self):\n"
#: The frame set to the video's aspect ratio, 8 units tall (the instructions' recipe).
FITTED = ("from manim import *\n\nconfig.frame_height = 8.0\n"
          "config.frame_width = 8.0 * config.pixel_width / config.pixel_height\n\n"
          "class GeneratedScene(Scene):\n    def construct(self):\n")
#: A red dot moving right at 1 unit per second for 1 s, then holding for `hold` seconds.
MOVING = HEADER + """\
        dot = Dot(point=LEFT * 2, radius=0.4, color="#f34f46")
        self.add(dot)
        self.play(dot.animate.shift(RIGHT * 1), run_time=1, rate_func=linear)
        self.wait({hold})
"""


@pytest.fixture(scope="module")
def engine():
    eng = ManimEngine()
    yield eng
    eng.close()


def program(source: str) -> Program:
    return Program(language="python", source=source)


def contract(**kw) -> RenderContract:
    base = {"fps": 10.0, "n_frames": 12, "width": 160, "height": 120, "timeout_s": 60.0}
    return RenderContract(**{**base, **kw})


def red_centre_x(frame: np.ndarray) -> float:
    mask = np.all(frame == (243, 79, 70), axis=2)
    return float(np.nonzero(mask)[1].mean()) + 0.5


# ------------------------------------------------------------------------- extract / validate
def test_extract_takes_the_python_block(engine):
    reply = ("The ball rolls.\n\n```json\n{\"bodies\": []}\n```\n\n```python\n"
             + MOVING.format(hold=1) + "```\n")
    prog = engine.extract(reply)
    assert prog.language == "python" and "class GeneratedScene" in prog.source
    assert prog.spec == {"bodies": []}


@pytest.mark.parametrize("reply, failure", [
    ("no code at all", FailureClass.NO_CODE),
    ("```html\n<html><script></script></html>\n```", FailureClass.WRONG_LANGUAGE),
    ("```python\nfrom manim import *\nclass GeneratedScene(Scene):\n", FailureClass.TRUNCATED),
])
def test_extract_failures(engine, reply, failure):
    with pytest.raises(ProgramRejected) as err:
        engine.extract(reply)
    assert err.value.failure is failure


def test_validate_classes(engine):
    engine.validate(program(MOVING.format(hold=1)))
    engine.validate(program("import manim\nclass GeneratedScene(manim.MovingCameraScene):\n"
                            "    def construct(self):\n        pass\n"))
    with pytest.raises(ProgramRejected) as err:
        engine.validate(program("from manim import *\nx = (1,\nprint(x)\n"))
    assert err.value.failure is FailureClass.SYNTAX_ERROR and "line" in str(err.value)
    with pytest.raises(ProgramRejected) as err:
        engine.validate(program("from manim import *\nclass Other(Scene):\n    pass\n"))
    assert err.value.failure is FailureClass.NO_CODE
    with pytest.raises(ProgramRejected) as err:
        engine.validate(program("class GeneratedScene:\n    pass\n"))
    assert err.value.failure is FailureClass.NO_CODE


def test_instructions_ask_for_text_not_mathtex(engine):
    text = engine.instructions("2d")
    assert text == INSTRUCTIONS
    assert "GeneratedScene(Scene)" in text and "Text(" in text and "MathTex" in text
    assert "white background" in text and "no physics engine" in text.lower()
    # the frame rule: Manim's default frame unless the program sets one, letterboxed
    assert "14.22 x 8 units" in text and "config.frame_width" in text and "bars" in text


# ------------------------------------------------------------------------- render
def test_renders_exact_frame_count_size_and_timing(engine):
    c = contract()
    source = MOVING.format(hold=0.3).replace(HEADER, FITTED)
    res = engine.render(program(source), c)  # 1.3 s of scene for a 1.2 s clip
    assert res.ok, (res.failure, res.error, res.logs[-10:])
    assert res.frames.shape == (12, 120, 160, 3) and res.frames.dtype == np.uint8
    assert tuple(res.frames[0, 0, 0]) == (255, 255, 255)  # white background
    assert res.logs[0].startswith(f"sandbox: {res.isolation};")
    from visphy_core.sandbox.process import isolation_level
    assert res.isolation == isolation_level()
    assert res.flags == []  # the frame has the clip's shape: nothing was resized
    px_per_unit = 120 / 8.0  # frame 8 units tall, filling the clip
    xs = [red_centre_x(f) for f in res.frames]
    for k in range(11):  # frame k shows scene time k / fps
        expect = 80 + (-2 + min(k / 10, 1.0)) * px_per_unit
        assert abs(xs[k] - expect) < 0.6, (k, xs[k], expect)


#: Unit squares at the left and right edges (x = ±6.5) and the top and bottom (y = ±3.4) of
#: Manim's default 14.22 x 8 frame, in four distinct colours.
EDGES = """\
        for colour, x, y in (("#ff0000", -6.5, 0), ("#0000ff", 6.5, 0),
                             ("#00aa00", 0, 3.4), ("#aa00aa", 0, -3.4)):
            self.add(Square(side_length=1, fill_color=colour, fill_opacity=1,
                            stroke_width=0).move_to([x, y, 0]))
        self.wait(0.5)
"""
EDGE_COLOURS = {(255, 0, 0): (-6.5, 0), (0, 0, 255): (6.5, 0), (0, 170, 0): (0, 3.4),
                (170, 0, 170): (0, -3.4)}


def assert_frame_shows_edges(frame: np.ndarray, px_per_unit: float, x0: float, y0: float,
                             fit_w: int, fit_h: int):
    """Each edge square is whole, where the letterboxed 14.22 x 8 frame puts it."""
    h, w = frame.shape[:2]
    for colour, (x, y) in EDGE_COLOURS.items():
        ys, xs = np.nonzero(np.all(frame == colour, axis=2))
        assert len(xs) >= (px_per_unit - 2) ** 2, (colour, len(xs))  # whole (edges blend)
        cx = x0 + fit_w / 2 + x * px_per_unit
        cy = y0 + fit_h / 2 - y * px_per_unit
        assert abs(xs.mean() + 0.5 - cx) < 1 and abs(ys.mean() + 0.5 - cy) < 1, colour


@pytest.mark.parametrize("configure", [
    "", "config.frame_width = 128 / 9\nconfig.frame_height = 8\n",
    "config.pixel_width = 1920\nconfig.pixel_height = 1080\n"],
    ids=["default", "frame_16x9", "pixels_16x9"])
def test_16_9_frame_is_letterboxed_not_cropped(engine, configure):
    """A program written for Manim's 16:9 frame (its default, or set explicitly) on a square
    clip: everything in the frame is shown, scaled uniformly, with white bars above/below."""
    source = HEADER.replace("from manim import *\n", "from manim import *\n" + configure)
    res = engine.render(program(source + EDGES), contract(width=160, height=160, n_frames=4))
    assert res.ok, (res.failure, res.error, res.logs[-5:])
    assert res.flags == ["canvas_resized"]
    assert any("letterboxed into the 160x160 clip: 160x90 px at (0, 35)" in line
               for line in res.logs), res.logs
    frame = res.frames[0]
    assert np.all(frame[:35] == 255) and np.all(frame[125:] == 255)  # background-coloured bars
    assert_frame_shows_edges(frame, 160 / (128 / 9), 0, 35, 160, 90)


def test_tall_frame_is_pillarboxed_in_the_programs_background(engine):
    """A frame narrower than the clip gets bars left and right, in the program's own background
    colour; the program's frame_rate is its own too (clip frame k = t = k / fps)."""
    source = ("from manim import *\nconfig.frame_width = 4\nconfig.frame_height = 8\n"
              "config.background_color = '#202020'\nconfig.frame_rate = 30\n\n"
              "class GeneratedScene(Scene):\n    def construct(self):\n"
              "        dot = Dot([-1.5, 0, 0], radius=0.3, color='#f34f46')\n"
              "        self.add(dot)\n"
              "        for _ in range(40):\n"
              "            dot.shift(RIGHT * (1 / 30))\n"
              "            self.wait(1 / 30)\n")
    res = engine.render(program(source), contract())  # 160 x 120 at 10 fps
    assert res.ok, (res.failure, res.error, res.logs[-5:])
    assert res.flags == ["canvas_resized"]
    # 4 x 8 units into 160 x 120: 60 x 120 px at x = 50, 15 px per unit
    frame = res.frames[0]
    assert np.all(frame[:, :50] == 0x20) and np.all(frame[:, 110:] == 0x20)
    assert tuple(frame[5, 55]) == (0x20, 0x20, 0x20)
    xs = [red_centre_x(f) for f in res.frames]
    for k in range(12):  # the dot moves 1 unit/s in scene time: 15 px/s in the clip
        expect = 80 + (-1.5 + min(k / 10 + 1 / 30, 40 / 30)) * 15
        assert abs(xs[k] - expect) < 0.6, (k, xs[k], expect)


def test_runtime_error_keeps_the_frames_before_it(engine):
    source = FITTED + """\
        dot = Dot(point=LEFT * 2, radius=0.4, color="#f34f46")
        self.add(dot)
        self.play(dot.animate.shift(RIGHT * 1), run_time=0.5, rate_func=linear)
        raise ValueError("after half a second")
"""
    res = engine.render(program(source), contract())
    assert res.failure is FailureClass.RUNTIME_ERROR and "ValueError" in res.error
    assert res.flags == ["partial_clip"] and res.frames is None
    assert res.partial_frames.shape == (5, 120, 160, 3)  # t = 0, 0.1, ..., 0.4
    xs = [red_centre_x(f) for f in res.partial_frames]
    for k, x in enumerate(xs):
        assert abs(x - (80 + (-2 + 2 * k / 10) * 15)) < 0.6, (k, x)  # 2 units/s
    # an error before any frame: no partial clip
    res = engine.render(program(FITTED + "        raise ValueError('at once')\n"), contract())
    assert res.failure is FailureClass.RUNTIME_ERROR
    assert res.flags == [] and res.partial_frames is None


def test_runner_is_a_module_copied_into_the_sandbox(tmp_path):
    """The trusted runner is the shipped module file, copied as it is into the work dir."""
    from visphy_plugins.engines import manim as manim_engine

    runner = manim_engine.RUNNER
    assert runner.is_file() and runner.parent == Path(manim_engine.__file__).resolve().parent
    compile(runner.read_text(), str(runner), "exec")
    eng = ManimEngine({"keep_workdir": True})
    res = eng.render(program(MOVING.format(hold=0)), contract(n_frames=3))
    assert res.ok, (res.failure, res.error)
    kept = Path(res.logs[-1].removeprefix("work dir kept: "))
    try:
        assert (kept / runner.name).read_bytes() == runner.read_bytes()
    finally:
        import shutil
        shutil.rmtree(kept, ignore_errors=True)


def test_short_scene_holds_last_frame_long_scene_is_truncated(engine):
    short = engine.render(program(MOVING.format(hold=0.1)), contract(n_frames=20))
    assert short.ok and short.frames.shape[0] == 20
    assert all(np.array_equal(short.frames[10], f) for f in short.frames[10:])
    long = engine.render(program(MOVING.format(hold=600)), contract(n_frames=8))
    assert long.ok and long.frames.shape[0] == 8 and long.wall_s < 30


def test_same_program_same_frames(engine):
    src = HEADER + """\
        import random
        import numpy as np
        dots = VGroup(*[Dot(point=[random.uniform(-3, 3), np.random.uniform(-2, 2), 0],
                            color=BLUE) for _ in range(5)])
        label = Text("visphy", color=BLACK).scale(0.6).to_edge(UP)
        self.add(dots, label)
        self.play(Rotate(dots, angle=PI / 3), run_time=1)
"""
    a = engine.render(program(src), contract())
    b = engine.render(program(src), contract())
    assert a.ok and b.ok, (a.error, b.error)
    assert np.array_equal(a.frames, b.frames)
    c = engine.render(program(src), contract(seed=1))
    assert c.ok and not np.array_equal(a.frames, c.frames)  # contract.seed seeds random/numpy


@pytest.mark.parametrize("body, failure, needle", [
    ("        x = 1 / 0\n", FailureClass.RUNTIME_ERROR, "ZeroDivisionError"),
    ("        self.add(MathTex('x^2'))\n        self.wait(1)\n", FailureClass.RUNTIME_ERROR,
     "use Text"),
    ("        import numpy as np\n        a = np.ones(10 ** 10, dtype=np.uint8)\n",
     FailureClass.RESOURCE_LIMIT, "memory limit"),
    ("        self.add(Circle(color=RED))\n", FailureClass.BLANK_OUTPUT, "no frame"),
    ("        self.wait(1)\n", FailureClass.BLANK_OUTPUT, "flat colour"),
])
def test_failure_classes(engine, body, failure, needle):
    res = engine.render(program(HEADER + body), contract())
    assert res.failure is failure and needle in (res.error or ""), (res.failure, res.error)
    assert res.frames is None


def test_runtime_error_names_the_program_line(engine):
    res = engine.render(program(HEADER + "        y = 2\n        undefined_name + y\n"),
                        contract())
    assert res.failure is FailureClass.RUNTIME_ERROR
    assert "NameError" in res.error and "program line 6" in res.error


def test_timeout(engine):
    res = engine.render(program(HEADER + "        while True:\n            pass\n"),
                        contract(timeout_s=3.0))
    assert res.failure is FailureClass.TIMEOUT and res.wall_s < 20


NET_PROBE = """\
        import json, os, socket
        seen = {{"netns": os.stat("/proc/self/ns/net").st_ino,
                "interfaces": sorted(name for _, name in socket.if_nameindex())}}
        try:
            socket.create_connection(("127.0.0.1", {port}), timeout=3).close()
            seen["connect"] = "connected"
        except OSError as exc:
            seen["connect"] = type(exc).__name__
        raise RuntimeError("NETPROBE" + json.dumps(seen) + "NETPROBE")
"""


def test_program_has_no_network(engine):
    """The program runs in a network namespace of its own: another namespace than the host's,
    no interface but loopback, and a port that listens on the host's 127.0.0.1 (reachable from
    here) is not reachable from there."""
    import os
    import socket

    from visphy_core.sandbox.process import isolation_available

    if not isolation_available()[0]:
        pytest.skip("no bubblewrap sandbox here")
    host_netns = os.stat("/proc/self/ns/net").st_ino
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
        socket.create_connection(("127.0.0.1", port), timeout=3).close()  # reachable from here
        listener.accept()[0].close()
        listener.settimeout(0.5)
        res = engine.render(program(HEADER + NET_PROBE.format(port=port)), contract())
        with pytest.raises(TimeoutError):  # and nothing came from the program
            listener.accept()
    assert res.failure is FailureClass.RUNTIME_ERROR and "NETPROBE" in (res.error or ""), res
    assert res.isolation.startswith("bwrap:") and "netns" in res.isolation
    seen = json.loads(res.error.split("NETPROBE")[1])
    assert seen["netns"] != host_netns
    assert seen["interfaces"] == ["lo"]
    assert seen["connect"] != "connected", seen  # refused, unreachable or denied: an OSError


def test_program_runs_as_nobody_and_sees_no_host_file(engine, tmp_path):
    from visphy_core.sandbox.process import isolation_available

    if not isolation_available()[0]:
        pytest.skip("no bubblewrap sandbox here")
    host = tmp_path / "host.txt"
    host.write_text("host")
    host.chmod(0o644)
    body = (f"        import os\n        assert os.getuid() == 65534, os.getuid()\n"
            f"        open({str(host)!r}).read()\n")
    res = engine.render(program(HEADER + body), contract())
    assert res.failure is FailureClass.RUNTIME_ERROR and "FileNotFoundError" in res.error


def test_file_size_limit_is_a_resource_limit():
    eng = ManimEngine({"file_size_mb": 8})  # raised to fit the frames: 64 MB here
    res = eng.render(program(HEADER + "        open('big.bin', 'wb').write(b'x' * (100 << 20))\n"),
                     contract())
    assert res.failure is FailureClass.RESOURCE_LIMIT and "file size limit" in res.error, res.error


def test_disk_quota_is_a_resource_limit():
    eng = ManimEngine({"disk_mb": 70, "file_size_mb": 8})
    body = ("        import os, time\n        for i in range(100):\n"
            "            open(f'f{i}', 'wb').write(os.urandom(4 << 20))\n"
            "        time.sleep(30)\n")
    res = eng.render(program(HEADER + body), contract(timeout_s=20))
    assert res.failure is FailureClass.RESOURCE_LIMIT and "disk quota" in res.error, res.error
    assert res.wall_s < 15


def test_refused_sandbox_is_an_infra_error(engine, monkeypatch):
    from visphy_core.sandbox import process as sp

    monkeypatch.setattr(sp, "_probe", lambda: (None, "bubblewrap (bwrap) is not installed"))
    monkeypatch.delenv(sp.ALLOW_UNISOLATED_ENV, raising=False)
    res = engine.render(program(MOVING.format(hold=0)), contract())
    assert res.failure is FailureClass.INFRA_ERROR
    assert "bubblewrap" in res.error and "allow_unisolated" in res.error


def test_config_schema_is_registered_and_typed():
    from dataclasses import fields

    from visphy_plugins.engines.manim import ManimConfig

    names = {f.name: f for f in fields(ManimConfig)}
    assert {"timeout_s", "memory_mb", "file_size_mb", "disk_mb", "keep_workdir"} <= set(names)
    assert names["timeout_s"].metadata["min"] >= 1 and names["memory_mb"].metadata["min"] > 0


# ------------------------------------------------------------------------- reference program
def colour_centres(frame: np.ndarray, colours) -> dict:
    """Centroid (px) of the pixels of each exact colour present in a frame."""
    out = {}
    for colour in colours:
        ys, xs = np.nonzero(np.all(frame == colour, axis=2))
        if len(xs):
            out[tuple(colour)] = np.array([xs.mean(), ys.mean()])
    return out


def reference_error(engine, scene, gt: np.ndarray) -> tuple[float, float]:
    """(mean object-centre error in px, mean PSNR) of the reference program against ``gt``."""
    from visphy_plugins.metrics.pixel import psnr_frame

    prog = engine.program_from_spec(scene)
    engine.validate(prog)
    res = engine.render(prog, RenderContract.for_scene(scene, timeout_s=120))
    assert res.ok, (res.failure, res.error, res.logs[-10:])
    assert res.frames.shape == gt.shape
    assert res.flags == []  # the reference frame fills the clip
    colours = {tuple(b["color_rgb"]) for b in scene.spec["bodies"]}
    errors = []
    for got, want in zip(res.frames, gt):
        a, b = colour_centres(got, colours), colour_centres(want, colours)
        errors += [float(np.hypot(*(a[c] - b[c]))) for c in a.keys() & b.keys()]
    assert errors
    return float(np.mean(errors)), float(np.mean([psnr_frame(g, w)
                                                   for g, w in zip(res.frames, gt)]))


def test_reference_program_tracks_ground_truth_handmade(engine, tmp_path):
    """Every hand-made mini scene (circles, boxes, a jar), against the exact rasteriser."""
    from mini_templates import mini_scenes

    from visphy_core.api.scene import Scene
    from visphy_core.infra.video import ClipInfo
    from visphy_plugins.datasets.visphybench.build import _npz_bytes
    from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d

    for spec, rollout in mini_scenes()[:3]:
        sid = spec["scene_id"]
        (tmp_path / f"{sid}.json").write_text(json.dumps(spec))
        (tmp_path / f"{sid}.npz").write_bytes(_npz_bytes(rollout, "2d"))
        w, h = spec["world"]["units"]["canvas_px"]
        scene = Scene(scene_id=sid, dim="2d", video_path=tmp_path / f"{sid}.mp4",
                      clip=ClipInfo(fps=spec["world"]["video_fps"],
                                    n_frames=spec["world"]["n_frames"], width=w, height=h),
                      spec_path=tmp_path / f"{sid}.json", trajectory_path=tmp_path / f"{sid}.npz")
        gt = render_clip_2d(spec, rollout.frame_poses)
        err, psnr = reference_error(engine, scene, gt)
        assert err <= 3.0 and psnr >= 30.0, (sid, err, psnr)


def test_reference_program_tracks_ground_truth_mini_split(engine, mini_scenes):
    """One scene of the generated benchmark's mini split, against its decoded reference clip."""
    scene = mini_scenes[0]
    err, psnr = reference_error(engine, scene, scene.reference_frames())
    assert err <= 3.0 and psnr >= 30.0, (scene.scene_id, err, psnr)


def test_reference_program_3d_not_implemented(engine):
    from visphy_core.api.scene import Scene
    from visphy_core.infra.video import ClipInfo

    scene = Scene(scene_id="14_tmpl_14", dim="3d", clip=ClipInfo(15.0, 75, 512, 512),
                  video_path=Path("/nonexistent.mp4"))
    with pytest.raises(NotImplementedError, match="3D"):
        engine.program_from_spec(scene)


def test_output_files_are_read_without_following_links(tmp_path):
    from visphy_plugins.engines.manim import _read_untrusted

    secret = tmp_path / "host_only.txt"
    secret.write_text("secret")
    (tmp_path / "frames.rgb").symlink_to(secret)
    (tmp_path / "big.rgb").write_bytes(b"x" * 100)
    assert _read_untrusted(tmp_path / "frames.rgb", 1 << 20) is None
    assert _read_untrusted(tmp_path / "big.rgb", 99) is None
    assert _read_untrusted(tmp_path / "big.rgb", 100) == b"x" * 100


def test_manim_chatter_goes_to_the_render_log_not_the_terminal(tmp_path):
    """A run (Hydra's logging on the terminal) renders with Manim: its "Reading config file"
    lines, printed while Manim imports on the host and in the sandbox, never reach the terminal
    (they used to appear inside the progress bars); the sandbox's are in the render log."""
    from conftest import FAST_METRICS, run_cli
    from visphy_plugins.testing.replies import MANIM_PROGRAM

    reply = tmp_path / "ball.py"
    reply.write_text(MANIM_PROGRAM)
    home = tmp_path / "home"
    proc = run_cli("model=replay", f"model.source={reply}", "engine=manim", "dataset=tiny",
                   "dataset.limit=1", "tracking=none", *FAST_METRICS, home=home, timeout=300)
    assert "Reading config file" not in proc.stdout + proc.stderr
    (log,) = (home / "runs").glob("*/scenes/*/render.log")
    assert "Reading config file" in log.read_text()
