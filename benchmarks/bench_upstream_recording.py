"""visphy's virtual-time capture against the upstream way of recording (wall-clock MediaRecorder),
in one run.

    .venv/bin/python benchmarks/bench_upstream_recording.py [--data-dir visphy-out/data] [--runs 2]
        [--gap 0.5] [--json out.json]

For each scene of the `mini` split the threejs reference program is rendered (a) by visphy with a
warm pool (virtual time, frames read back at exact times), on the fast path and on the PNG path
it replaced, and (b) as upstream does: real requestAnimationFrame, `setupRecording` starting a
MediaRecorder on the canvas stream and stopping after the clip's real duration. Before each
visphy render the benchmark waits ``--gap`` seconds, as a run spends time scoring between two
renders. Prints machine info (cores, CPU model, load average: the machine may be shared), wall
time per clip, decoded frame counts, whether two runs gave identical frames (the reason visphy
drives time virtually) and how many times faster visphy is than the recording.
"""

from __future__ import annotations

import argparse
import base64
import json
import statistics
import tempfile
import time
from pathlib import Path

from bench_render import TreeCpu
from machine import machine_info

UPSTREAM_RECORDER = """
window.setupRecording = (canvas, durationMs) => {
  const stream = canvas.captureStream(30);
  const recorder = new MediaRecorder(stream, { mimeType: 'video/webm' });
  const chunks = [];
  recorder.ondataavailable = (e) => chunks.push(e.data);
  recorder.onstop = async () => {
    const buf = await new Blob(chunks, { type: 'video/webm' }).arrayBuffer();
    let s = ''; const bytes = new Uint8Array(buf);
    for (let i = 0; i < bytes.length; i += 0x8000)
      s += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
    window.__recorded = btoa(s);
  };
  recorder.start();
  setTimeout(() => recorder.stop(), durationMs);
};
"""


def record_upstream(browser, html: str, vendor, width: int, height: int) -> tuple[float, bytes]:
    from urllib.parse import urlparse

    context = browser.new_context(viewport={"width": width, "height": height})

    def route(r):
        path = urlparse(r.request.url).path.lstrip("/")
        if path == "index.html":
            return r.fulfill(status=200, body=html.encode(), content_type="text/html")
        if path in vendor:
            return r.fulfill(status=200, body=vendor[path].read_bytes(),
                             content_type="text/javascript")
        return r.abort()

    context.route("**/*", route)
    context.add_init_script(UPSTREAM_RECORDER)
    page = context.new_page()
    start = time.perf_counter()
    page.goto("https://visphy.invalid/index.html")
    page.wait_for_function("() => window.__recorded !== undefined", timeout=60000)
    wall = time.perf_counter() - start
    data = base64.b64decode(page.evaluate("() => window.__recorded"))
    context.close()
    return wall, data


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--data-dir", default="visphy-out/data")
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--gap", type=float, default=0.5)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    from playwright.sync_api import sync_playwright

    from visphy_core.api.engine import RenderContract
    from visphy_core.infra.video import decode_video, frame_digest
    from visphy_core.sandbox.browser import CHROMIUM_ARGS, BrowserPool, find_chromium
    from visphy_plugins.datasets.visphybench.build import build_dataset
    from visphy_plugins.datasets.visphybench.loader import load_generated
    from visphy_plugins.engines.threejs import ThreeJsEngine

    start_info = machine_info()
    print(json.dumps(start_info))
    scenes = load_generated(build_dataset(Path(args.data_dir), split="mini", progress=False),
                            split="mini")
    engine = ThreeJsEngine()
    pools = {"fast": BrowserPool(), "png": BrowserPool(readback="png", prepare_pages=False)}
    for pool in pools.values():  # warm: browser started, first page prepared
        engine.pool = pool
        engine.render(engine.program_from_spec(scenes[0]), RenderContract.for_scene(scenes[0]))
    cpu = TreeCpu()
    cpu.sample()
    report = []
    with sync_playwright() as p, tempfile.TemporaryDirectory() as tmp:
        browser = p.chromium.launch(executable_path=find_chromium(), args=CHROMIUM_ARGS)
        for scene in scenes:
            program = engine.program_from_spec(scene)
            contract = RenderContract.for_scene(scene)
            times = {name: [] for name in pools}
            call_cpu = []
            digests = {name: [] for name in pools}
            up_times, up_counts, up_digests = [], [], []
            for run in range(args.runs):
                for name, pool in pools.items():
                    engine.pool = pool
                    time.sleep(args.gap)
                    c0 = cpu.sample()
                    t = time.perf_counter()
                    result = engine.render(program, contract)
                    times[name].append(time.perf_counter() - t)
                    if name == "fast":
                        call_cpu.append(cpu.sample() - c0)
                    digests[name].append([frame_digest(f) for f in result.frames])
                wall, webm = record_upstream(browser, engine.canonicalise(program.source),
                                             engine.vendor, contract.width, contract.height)
                path = Path(tmp) / f"{scene.scene_id}_{run}.webm"
                path.write_bytes(webm)
                frames, _ = decode_video(path)
                up_times.append(wall)
                up_counts.append(len(frames))
                up_digests.append([frame_digest(f) for f in frames])
            row = {
                "scene": scene.scene_id,
                "clip_s": contract.n_frames / contract.fps,
                "visphy_s": round(statistics.median(times["fast"]), 3),
                "visphy_cpu_s_during_call": round(statistics.median(call_cpu), 3),
                "visphy_png_path_s": round(statistics.median(times["png"]), 3),
                "visphy_frames": contract.n_frames,
                "visphy_identical_runs_and_paths": all(d == digests["fast"][0]
                                             for ds in digests.values() for d in ds),
                "upstream_s": round(statistics.median(up_times), 3),
                "upstream_frames": up_counts,
                "upstream_identical_runs": all(d == up_digests[0] for d in up_digests),
            }
            report.append(row)
            print(json.dumps(row), flush=True)
            cpu.sample()
        browser.close()
    for pool in pools.values():
        pool.close()
    visphy = statistics.median(r["visphy_s"] for r in report)
    upstream = statistics.median(r["upstream_s"] for r in report)
    summary = {"visphy_median_s": visphy,
               "visphy_png_path_median_s": statistics.median(r["visphy_png_path_s"]
                                                             for r in report),
               "visphy_cpu_s_during_call_median": statistics.median(
                   r["visphy_cpu_s_during_call"] for r in report),
               "upstream_median_s": upstream,
               "speedup_vs_upstream": round(upstream / visphy, 2),
               "machine_at_start": start_info, "machine_at_end": machine_info(),
               "peak_pss_tree_mib": round(cpu.peak_pss_mib, 1)}
    print(json.dumps(summary))
    if args.json:
        Path(args.json).write_text(json.dumps({"scenes": report, **summary}, indent=1) + "\n")


if __name__ == "__main__":
    main()
