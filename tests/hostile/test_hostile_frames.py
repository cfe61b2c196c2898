"""Hostile frames: what a sandboxed program leaves behind is decoded on the host under a budget.

Frames cross the sandbox boundary as files (Blender: ``frames/frame_*.png``; Manim: one raw
``frames.rgb``) that the program can rewrite after the trusted runner has finished (an
``atexit`` handler runs after ``result.json`` is written). The host reads them only through the
shared untrusted-media readers (`visphy_core.infra.png.read_untrusted_png`,
`visphy_core.infra.video.read_untrusted_frames` / `read_untrusted_raw_frames` / `VideoBudget`),
which check the header (PNG IHDR; a video's stream size, frame count, duration) against the render
contract before decoding anything, never follow links, cap file sizes and frame counts, and
charge the host's reading to the scene's wall-clock deadline.

The end-to-end cases run the render in a child process and read that process' own peak RSS
(``VmHWM`` of ``/proc/self/status``, which excludes the sandboxed renderer), so the host's
memory is measured, not Blender's. Not ``ru_maxrss``: Linux carries the parent's peak across
``fork``/``exec``, so a child of a large pytest worker starts with the worker's peak and any
growth below it reads as 0.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import textwrap
import time
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from visphy_core.api.engine import FailureClass, RenderContract
from visphy_core.infra.png import (
    PNG_HEADER_BYTES,
    DeadlineExceeded,
    FrameRejected,
    png_bytes,
    read_untrusted_png,
)
from visphy_core.infra.video import (
    ClipInfo,
    VideoBudget,
    decode_untrusted_video_timed,
    encode_video,
    load_clip_for,
    probe_untrusted_video,
    read_untrusted_frames,
    read_untrusted_raw_frames,
)

F = FailureClass
W, H = 64, 64
#: Peak host memory a render may add over the child's baseline (its imports). A 10000×10000
#: frame is 300 MB of RGB once decoded; the clip itself (a few 64×64 frames) is nothing.
RSS_BUDGET_MB = 300
#: Start-up and teardown of the sandbox on a loaded 2-core machine, on top of the limit.
MARGIN_S = 8.0


# ------------------------------------------------------------------------------ crafted PNGs
def _chunk(kind: bytes, data: bytes) -> bytes:
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))


def crafted_png(width: int, height: int, idat: bytes, depth: int = 8, colour: int = 2) -> bytes:
    """A PNG whose IHDR says ``width×height`` followed by ``idat`` as its only IDAT."""
    return (b"\x89PNG\r\n\x1a\n"
            + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0))
            + _chunk(b"IDAT", idat) + _chunk(b"IEND", b""))


def frame(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8)


GARBAGE = bytes(range(256)) * 64   # not a zlib stream: decoding it would fail


# ------------------------------------------------------------------------------ PNG header reader
def test_a_frame_whose_header_says_10000x10000_is_refused_without_decoding(tmp_path):
    # the IDAT is garbage: had anything been decompressed, the error would be a decode error
    path = tmp_path / "frame_00000.png"
    path.write_bytes(crafted_png(10000, 10000, GARBAGE))
    start = time.monotonic()
    with pytest.raises(FrameRejected) as err:
        read_untrusted_png(path, W, H)
    assert time.monotonic() - start < 1.0
    assert str(err.value) == ("frame_00000.png is 10000x10000 px, not the clip's 64x64: "
                              "refused before decoding")
    # the same garbage behind a header of the right size is decoded, and fails as such
    path.write_bytes(crafted_png(W, H, GARBAGE))
    with pytest.raises(FrameRejected, match="frame_00000.png does not decode"):
        read_untrusted_png(path, W, H)


def test_a_highly_compressible_10000x10000_png_is_refused_by_its_header(tmp_path):
    """The reproduction's frame: a real, valid 10000×10000 PNG of ~300 KB."""
    z = zlib.compressobj(9)
    row = b"\0" * (1 + 3 * 10000)
    idat = b"".join(z.compress(row) for _ in range(10000)) + z.flush()
    path = tmp_path / "frame_00003.png"
    path.write_bytes(crafted_png(10000, 10000, idat))
    assert path.stat().st_size < 400_000
    with pytest.raises(FrameRejected, match=r"10000x10000 px, not the clip's 64x64"):
        read_untrusted_png(path, W, H)


def test_good_frames_read_back_exactly(tmp_path):
    paths = []
    for k in range(3):
        paths.append(tmp_path / f"frame_{k:05d}.png")
        paths[-1].write_bytes(png_bytes(frame(k)))
    out = read_untrusted_frames(paths, W, H, max_frames=3)
    assert out.shape == (3, H, W, 3) and out.dtype == np.uint8
    for k in range(3):
        np.testing.assert_array_equal(out[k], frame(k))
    # RGBA and grey frames of the right size decode to RGB too
    rgba = np.dstack([frame(4), np.full((H, W, 1), 255, np.uint8)])
    paths[0].write_bytes(png_bytes(rgba))
    np.testing.assert_array_equal(read_untrusted_png(paths[0], W, H), frame(4))


@pytest.mark.parametrize("content, message", [
    (b"", "frame_00000.png is truncated (0 bytes: no complete PNG header)"),
    ("prefix", "frame_00000.png is truncated (20 bytes: no complete PNG header)"),
    (b"GIF89a" + bytes(100), "frame_00000.png is not a PNG file (no PNG signature)"),
    (b"\xff\xd8\xff\xe0" + bytes(100), "frame_00000.png is not a PNG file (no PNG signature)"),
    ("bad_depth", "frame_00000.png has an invalid PNG header (64x64 px, bit depth 3, colour "
                  "type 2)"),
    ("cut", "frame_00000.png does not decode"),
])
def test_truncated_and_non_png_files_are_refused(tmp_path, content, message):
    good = png_bytes(frame())
    if content == "prefix":
        content = good[:20]
    elif content == "bad_depth":
        content = crafted_png(W, H, GARBAGE, depth=3)
    elif content == "cut":
        content = good[:PNG_HEADER_BYTES + 10]
    path = tmp_path / "frame_00000.png"
    path.write_bytes(content)
    with pytest.raises(FrameRejected) as err:
        read_untrusted_png(path, W, H)
    assert str(err.value).startswith(message), str(err.value)


def test_links_fifos_and_oversized_files_are_refused_unread(tmp_path):
    target = tmp_path / "elsewhere.png"
    target.write_bytes(png_bytes(frame()))
    link = tmp_path / "frame_00001.png"
    link.symlink_to(target)
    with pytest.raises(FrameRejected) as err:
        read_untrusted_png(link, W, H)
    assert str(err.value) == ("frame_00001.png is a symbolic link, not a file the renderer "
                              "wrote: refused")
    fifo = tmp_path / "frame_00002.png"
    os.mkfifo(fifo)
    with pytest.raises(FrameRejected, match="frame_00002.png is not a regular file"):
        read_untrusted_png(fifo, W, H)   # opened non-blocking: no writer never hangs the host
    big = tmp_path / "frame_00003.png"
    with open(big, "wb") as f:           # a valid header, then 1 GB (sparse)
        f.write(png_bytes(frame()))
        f.truncate(1 << 30)
    with pytest.raises(FrameRejected) as err:
        read_untrusted_png(big, W, H)
    assert str(err.value) == (f"frame_00003.png is {1 << 30} bytes, more than a 64x64 PNG can "
                              f"need ({64 * (1 + 64 * 8) + (1 << 20)} bytes): refused unread")
    with pytest.raises(FrameRejected, match="frame_00004.png is missing"):
        read_untrusted_png(tmp_path / "frame_00004.png", W, H)


def test_more_frames_than_the_contract_are_refused_and_the_deadline_is_kept(tmp_path):
    paths = []
    for k in range(4):
        paths.append(tmp_path / f"frame_{k:05d}.png")
        paths[-1].write_bytes(png_bytes(frame(k)))
    with pytest.raises(FrameRejected, match="4 frame files, more than the clip's 3: refused"):
        read_untrusted_frames(paths, W, H, max_frames=3)
    with pytest.raises(DeadlineExceeded, match="frame 0 of 3 was not read yet"):
        read_untrusted_frames(paths[:3], W, H, max_frames=3, deadline=time.monotonic() - 1)


def test_raw_frames_are_refused_by_size_before_reading(tmp_path):
    raw = tmp_path / "frames.rgb"
    raw.write_bytes(np.stack([frame(0), frame(1)]).tobytes())
    np.testing.assert_array_equal(read_untrusted_raw_frames(raw, W, H, 3)[1], frame(1))
    with open(raw, "wb") as f:
        f.truncate(400 << 20)            # sparse: 400 MB announced, nothing allocated
    with pytest.raises(FrameRejected) as err:
        read_untrusted_raw_frames(raw, W, H, 3)
    assert str(err.value) == (f"frames.rgb is {400 << 20} bytes, more than the clip's 3 frames "
                              f"of 64x64 px ({3 * W * H * 3} bytes): refused unread")
    raw.write_bytes(b"x" * (W * H * 3 + 1))
    with pytest.raises(FrameRejected, match="not a whole number of 64x64 RGB frames"):
        read_untrusted_raw_frames(raw, W, H, 3)
    raw.unlink()
    raw.symlink_to("/dev/zero")
    with pytest.raises(FrameRejected, match="frames.rgb is a symbolic link"):
        read_untrusted_raw_frames(raw, W, H, 3)


# ------------------------------------------------------------------------------ the engines' use
def _fake_proc(**kw):
    base = dict(stdout="", stderr="", limit_hit=None, refused=False, returncode=0,
                timed_out=False, wall_s=1.0, isolation="test")
    return SimpleNamespace(**(base | kw))


def _blender_workdir(tmp_path: Path, n: int, data: bytes, extra: int = 0) -> Path:
    (tmp_path / "frames").mkdir()
    (tmp_path / "result.json").write_text(json.dumps({"status": "ok", "frames_rendered": n}))
    for k in range(n + extra):
        (tmp_path / "frames" / f"frame_{k:05d}.png").write_bytes(data)
    return tmp_path


def test_blender_host_side_refuses_a_frame_of_another_size(tmp_path):
    from visphy_core.sandbox.process import Limits
    from visphy_plugins.engines.blender import BlenderEngine

    contract = RenderContract(fps=10, n_frames=3, width=W, height=H, timeout_s=20)
    work = _blender_workdir(tmp_path, 3, crafted_png(10000, 10000, GARBAGE))
    result = BlenderEngine({})._collect(_fake_proc(), work, contract, Limits(),
                                        time.monotonic() + 20)
    assert result.failure is F.RUNTIME_ERROR and result.frames is None
    assert result.error == (
        "frame output refused: frame_00000.png is 10000x10000 px, not the clip's 64x64: refused "
        "before decoding (the runner writes every frame as an 8-bit PNG at the clip's size: the "
        "program changed the render settings or rewrote the frame files)")
    assert "canvas_resized" not in result.flags


def test_blender_host_side_ignores_extra_files_and_charges_the_deadline(tmp_path):
    from visphy_core.sandbox.process import Limits
    from visphy_plugins.engines.blender import BlenderEngine, _frame_files

    contract = RenderContract(fps=10, n_frames=3, width=W, height=H, timeout_s=20)
    work = _blender_workdir(tmp_path, 3, png_bytes(frame()), extra=500)
    (work / "frames" / "frame_junk.png").write_bytes(crafted_png(10000, 10000, GARBAGE))
    assert [p.name for p in _frame_files(work / "frames", 3)] == [
        "frame_00000.png", "frame_00001.png", "frame_00002.png"]
    ok = BlenderEngine({})._collect(_fake_proc(), work, contract, Limits(),
                                    time.monotonic() + 20)
    assert ok.failure is None and ok.frames.shape == (3, H, W, 3)
    late = BlenderEngine({})._collect(_fake_proc(), work, contract, Limits(),
                                      time.monotonic() - 0.1)
    assert late.failure is F.TIMEOUT and late.frames is None
    assert late.error == ("no result within the time limit of 20 s: reading the rendered frames "
                          "on the host went past it (frame 0 of 3 was not read yet)")


def test_blender_partial_clip_is_read_under_the_same_rules(tmp_path):
    from visphy_core.sandbox.process import Limits
    from visphy_plugins.engines.blender import BlenderEngine

    contract = RenderContract(fps=10, n_frames=3, width=W, height=H, timeout_s=20)
    work = _blender_workdir(tmp_path, 2, crafted_png(10000, 10000, GARBAGE))
    (work / "result.json").write_text(json.dumps(
        {"status": "runtime_error", "error": "boom", "frames_rendered": 2}))
    result = BlenderEngine({})._collect(_fake_proc(returncode=3), work, contract, Limits(),
                                        time.monotonic() + 20)
    assert result.failure is F.RUNTIME_ERROR and result.error == "boom"
    assert result.partial_frames is None and "partial_clip" not in result.flags
    assert any(line.startswith("partial clip refused: frame_00000.png is 10000x10000 px")
               for line in result.logs)


# ------------------------------------------------------------------------------ videos
def _clip(path: Path, width: int, height: int, n: int = 10, fps: float = 10) -> Path:
    frames = [np.full((height, width, 3), (40 + 5 * k) % 256, np.uint8) for k in range(n)]
    return encode_video(frames, path, fps)


def _corrupt_payload(path: Path) -> None:
    """Overwrite the coded frames (the ``mdat`` box's payload) with garbage: a decoder would
    fail or produce noise; only the header (``moov``) is intact."""
    data = bytearray(path.read_bytes())
    at = data.find(b"mdat")
    size = struct.unpack(">I", data[at - 4:at])[0]
    data[at + 4:at - 4 + size] = bytes((i * 151) & 0xFF for i in range(size - 8))
    path.write_bytes(bytes(data))


def test_a_video_of_the_wrong_size_is_refused_from_its_header(tmp_path):
    path = _clip(tmp_path / "reply.mp4", 96, 64)
    _corrupt_payload(path)   # refused by the header alone: nothing was decoded
    with pytest.raises(FrameRejected) as err:
        decode_untrusted_video_timed(path, VideoBudget(size=(W, H)))
    assert str(err.value) == "reply.mp4 is 96x64 px, not the clip's 64x64: refused before decoding"
    with pytest.raises(FrameRejected) as err:
        probe_untrusted_video(path, VideoBudget(max_side=80))
    assert str(err.value) == ("reply.mp4 is 96x64 px, beyond the decoding budget (80 px a side, "
                              f"{8192 * 4352} pixels a frame): refused before decoding")
    with pytest.raises(FrameRejected, match="reply.mp4 announces 10 frames, more than the 5"):
        probe_untrusted_video(path, VideoBudget(max_frames=5))


def test_untrusted_videos_decode_within_the_budget(tmp_path):
    path = _clip(tmp_path / "reply.mp4", W, H, n=10)
    frames, times, info = decode_untrusted_video_timed(path, VideoBudget(size=(W, H)))
    assert frames.shape == (10, H, W, 3) and info.n_frames == 10
    np.testing.assert_allclose(times, np.arange(10) / 10, atol=1e-3)
    with pytest.raises(FrameRejected, match="needs more than 20000 decoded pixels"):
        decode_untrusted_video_timed(path, VideoBudget(max_total_pixels=20000))
    with pytest.raises(DeadlineExceeded):
        decode_untrusted_video_timed(path, VideoBudget(deadline=time.monotonic() - 1))
    # a model's clip of another size and rate is fitted as it is decoded
    big = _clip(tmp_path / "big.mp4", 256, 128, n=40, fps=40)
    out = load_clip_for(big, ClipInfo(fps=10, n_frames=10, width=W, height=H))
    assert out.shape == (10, H, W, 3)
    # links and non-video files are refused before FFmpeg sees them
    link = tmp_path / "link.mp4"
    link.symlink_to(path)
    with pytest.raises(FrameRejected, match="link.mp4 is a symbolic link"):
        load_clip_for(link, ClipInfo(fps=10, n_frames=10, width=W, height=H))
    playlist = tmp_path / "reply2.mp4"
    playlist.write_text("#EXTM3U\n#EXTINF:1,\nfile:///etc/passwd\n")
    with pytest.raises(FrameRejected, match="reply2.mp4 is not an MP4/MOV or Matroska/WebM"):
        load_clip_for(playlist, ClipInfo(fps=10, n_frames=10, width=W, height=H))


# ------------------------------------------------------------------------------ end to end
#: Runs one render in a fresh interpreter and prints its own peak RSS growth (RUSAGE_SELF:
#: the sandboxed renderer is a child and is not counted) and the render's wall time.
CHILD = r'''
import json, sys, time
spec = json.loads(sys.argv[1])
import numpy, PIL.Image, av  # the decoders' own imports belong to the baseline
from visphy_core.api.engine import Program, RenderContract
if spec["kind"] == "blender":
    from visphy_plugins.engines.blender import BlenderEngine as Engine
else:
    from visphy_plugins.engines.manim import ManimEngine as Engine
engine = Engine(spec["cfg"])
program = Program("python", open(spec["program"]).read())
def peak_kb():  # this process' own peak RSS (VmHWM: reset by exec, unlike ru_maxrss)
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))


before = peak_kb()
start = time.monotonic()
result = engine.render(program, RenderContract(**spec["contract"]))
took = time.monotonic() - start
after = peak_kb()
print("RESULT " + json.dumps({"failure": result.failure and result.failure.value,
                              "error": result.error, "took": took,
                              "rss_growth_mb": (after - before) / 1024,
                              "logs": result.logs[-6:]}))
'''


def run_child(tmp_path: Path, kind: str, source: str, contract: dict, cfg: dict) -> dict:
    program = tmp_path / "program.py"
    program.write_text(source)
    spec = {"kind": kind, "program": str(program), "contract": contract, "cfg": cfg}
    proc = subprocess.run([sys.executable, "-c", CHILD, json.dumps(spec)], capture_output=True,
                          text=True, timeout=contract["timeout_s"] + 120)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, (proc.returncode, proc.stdout[-2000:], proc.stderr[-2000:])
    return json.loads(lines[-1][len("RESULT "):])


#: A valid Blender scene (a red square moving right) ...
B_SCENE = r'''
import bpy
scene = bpy.context.scene
W, H = scene.render.resolution_x, scene.render.resolution_y
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
scene.collection.objects.link(cam)
cam.data.type = "ORTHO"; cam.data.ortho_scale = W
cam.location = (W / 2, H / 2, 100)
scene.camera = cam
scene.world = bpy.data.worlds.new("w"); scene.world.color = (1, 1, 1)
scene.display.shading.light = "FLAT"
scene.display.shading.color_type = "MATERIAL"
mat = bpy.data.materials.new("red"); mat.diffuse_color = (0.9, 0.08, 0.06, 1)
mesh = bpy.data.meshes.new("sq")
mesh.from_pydata([(0, 0, 0), (16, 0, 0), (16, 16, 0), (0, 16, 0)], [], [(0, 1, 2, 3)])
mesh.materials.append(mat)
sq = bpy.data.objects.new("sq", mesh); scene.collection.objects.link(sq)
for f in range(scene.frame_start, scene.frame_end + 1):
    sq.location = (2 + 2 * (f - scene.frame_start), 20, 0)
    sq.keyframe_insert("location", frame=f)
'''

#: ... whose atexit handler, after the runner wrote result.json, rewrites every frame as a valid
#: 10000×10000 PNG of ~292 KB (300 MB of pixels each once decoded).
B_ATEXIT_BOMB = B_SCENE + r'''
import atexit, glob, struct, zlib

def _chunk(kind, data):
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

def _bomb():
    z = zlib.compressobj(9)
    row = b"\0" * (1 + 3 * 10000)
    idat = b"".join(z.compress(row) for _ in range(10000)) + z.flush()
    png = (b"\x89PNG\r\n\x1a\n"
           + _chunk(b"IHDR", struct.pack(">IIBBBBB", 10000, 10000, 8, 2, 0, 0, 0))
           + _chunk(b"IDAT", idat) + _chunk(b"IEND", b""))
    for path in sorted(glob.glob("frames/frame_*.png")):
        with open(path, "wb") as f:
            f.write(png)
    print("rewrote", len(glob.glob("frames/frame_*.png")), "frames,", len(png), "bytes each")

atexit.register(_bomb)
'''

BLENDER_CONTRACT = {"fps": 10, "n_frames": 20, "width": W, "height": H, "timeout_s": 20.0}


@pytest.mark.blender
def test_blender_atexit_rewrites_every_frame_as_10000x10000(tmp_path):
    from visphy_core.sandbox.process import isolation_available
    from visphy_plugins.engines.blender import find_blender_python

    if find_blender_python() is None:
        pytest.skip("Blender venv missing: run scripts/setup_blender.sh")
    if not isolation_available()[0]:
        pytest.skip(f"no bubblewrap sandbox here: {isolation_available()[1]}")
    out = run_child(tmp_path, "blender", B_ATEXIT_BOMB, BLENDER_CONTRACT,
                    {"memory_mb": 3072, "threads": 1})
    limit = BLENDER_CONTRACT["timeout_s"]
    assert out["took"] <= limit + MARGIN_S, out
    assert out["failure"] == "runtime_error", out
    assert out["error"].startswith("frame output refused: frame_00000.png is 10000x10000 px, not "
                                   "the clip's 64x64: refused before decoding"), out
    assert out["rss_growth_mb"] < RSS_BUDGET_MB, out


#: A Manim program that, from inside the runner's process, replaces the runner's frame writer:
#: frames.rgb becomes a 400 MB (sparse) file, or a link to /dev/zero.
M_SCENE = r'''
from manim import *
import __main__ as runner
import os

def _huge(self):
    with open("frames.rgb", "wb") as f:
        f.truncate(400 << 20)

def _link(self):
    os.symlink("/dev/zero", "frames.rgb")

runner.Capture.write = __WRITER__

class GeneratedScene(Scene):
    def construct(self):
        d = Dot(point=LEFT, radius=0.5, color="#f34f46")
        self.add(d)
        self.play(d.animate.shift(RIGHT), run_time=0.3)
'''

MANIM_CONTRACT = {"fps": 10, "n_frames": 3, "width": W, "height": H, "timeout_s": 20.0}


@pytest.mark.manim
@pytest.mark.parametrize("writer, message", [
    ("_huge", f"frame output refused: frames.rgb is {400 << 20} bytes, more than the clip's 3 "
              f"frames of 64x64 px ({3 * W * H * 3} bytes): refused unread"),
    ("_link", "frame output refused: frames.rgb is a symbolic link, not a file the renderer "
              "wrote: refused"),
])
def test_manim_program_replaces_the_frame_file(tmp_path, writer, message):
    pytest.importorskip("manim")
    from visphy_core.sandbox.process import isolation_available

    if not isolation_available()[0]:
        pytest.skip(f"no bubblewrap sandbox here: {isolation_available()[1]}")
    out = run_child(tmp_path, "manim", M_SCENE.replace("__WRITER__", writer), MANIM_CONTRACT,
                    {"memory_mb": 1536})
    assert out["took"] <= MANIM_CONTRACT["timeout_s"] + MARGIN_S, out
    assert out["failure"] == "runtime_error", out
    assert out["error"].startswith(message), out
    assert out["rss_growth_mb"] < RSS_BUDGET_MB, out


def test_the_child_harness_measures_host_memory(tmp_path):
    """Self-check of the RSS measurement: a child that decodes one 10000×10000 PNG the old
    way (Pillow, no header check) shows far more than the budget."""
    z = zlib.compressobj(9)
    row = b"\0" * (1 + 3 * 10000)
    idat = b"".join(z.compress(row) for _ in range(10000)) + z.flush()
    path = tmp_path / "bomb.png"
    path.write_bytes(crafted_png(10000, 10000, idat))
    code = textwrap.dedent(f"""
        import numpy
        from PIL import Image
        def peak_kb():
            with open("/proc/self/status") as status:
                return next(int(line.split()[1]) for line in status
                            if line.startswith("VmHWM:"))
        before = peak_kb()
        with Image.open({str(path)!r}) as im:
            arr = numpy.asarray(im.convert("RGB"))
        print((peak_kb() - before) / 1024)
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert float(proc.stdout.split()[-1]) > RSS_BUDGET_MB


def test_decode_png_can_refuse_by_header_before_decoding():
    from visphy_core.infra.png import decode_png

    np.testing.assert_array_equal(decode_png(png_bytes(frame()), max_pixels=W * H), frame())
    with pytest.raises(FrameRejected, match="the image is 10000x10000 px, more than the 4096 "
                                            "pixels allowed: refused before decoding"):
        decode_png(crafted_png(10000, 10000, GARBAGE), max_pixels=W * H)


def test_a_page_cannot_make_the_host_decode_a_huge_canvas():
    """Browser readback: a raw or run-length payload, a canvas PNG or a screenshot claiming more
    than `MAX_FRAME_PIXELS` is refused before it is expanded or decoded."""
    import base64
    import struct
    import zlib

    import numpy as np

    from visphy_core.infra.png import FrameRejected
    from visphy_core.sandbox import readback

    side = 20000
    runs = np.array([side * side, 0xFFFFFFFF], dtype="<u4").tobytes()
    with pytest.raises(readback.ReadbackError, match="outside the readback budget"):
        readback.raw_to_rgb({"width": side, "height": side,
                             "runs": base64.b64encode(runs).decode()})

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", b"garbage") + chunk(b"IEND", b""))
    with pytest.raises(FrameRejected):
        readback.png_data_url_to_rgb("data:image/png;base64," + base64.b64encode(png).decode())
    with pytest.raises(FrameRejected):
        readback.png_bytes_to_rgb(png)
    small = np.full((4, 4, 3), 200, np.uint8)
    from visphy_core.infra.png import png_bytes

    assert (readback.png_bytes_to_rgb(png_bytes(small)) == small).all()
