"""visphy's virtual-time capture against the upstream way of recording (wall-clock MediaRecorder).

    .venv/bin/python benchmarks/bench_upstream_recording.py [--data-dir visphy-out/data] [--runs 2]

For each scene of the `mini` split the engine's reference program is rendered (a) by visphy with a
warm pool (virtual time, frames read back at exact times) and (b) as upstream does: real
requestAnimationFrame, `setupRecording` starting a MediaRecorder on the canvas stream and stopping
after the clip's real duration. Prints wall time per clip, decoded frame counts and whether two
runs gave identical frames — the reason visphy drives time virtually.
"""

from __future__ import annotations

import argparse
import base64
import json
import statistics
import tempfile
import time
from pathlib import Path

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
    args = parser.parse_args()

    from playwright.sync_api import sync_playwright

    from visphy_plugins.datasets.visphybench.build import build_dataset
    from visphy_plugins.datasets.visphybench.loader import load_generated
    from visphy_core.engine import RenderContract
    from visphy_core.sandbox.browser import CHROMIUM_ARGS, find_chromium
    from visphy_core.video import decode_video, frame_digest
    from visphy_plugins.engines.threejs import ThreeJsEngine

    scenes = load_generated(build_dataset(Path(args.data_dir), split="mini", progress=False),
                            split="mini")
    engine = ThreeJsEngine()
    engine.render(engine.program_from_spec(scenes[0]), RenderContract.for_scene(scenes[0]))
    report = []
    with sync_playwright() as p, tempfile.TemporaryDirectory() as tmp:
        browser = p.chromium.launch(executable_path=find_chromium(), args=CHROMIUM_ARGS)
        for scene in scenes:
            program = engine.program_from_spec(scene)
            contract = RenderContract.for_scene(scene)
            visphy_times, visphy_digests = [], []
            up_times, up_counts, up_digests = [], [], []
            for run in range(args.runs):
                t = time.perf_counter()
                result = engine.render(program, contract)
                visphy_times.append(time.perf_counter() - t)
                visphy_digests.append([frame_digest(f) for f in result.frames])
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
                "visphy_s": round(statistics.median(visphy_times), 3),
                "visphy_frames": contract.n_frames,
                "visphy_identical_runs": all(d == visphy_digests[0] for d in visphy_digests),
                "upstream_s": round(statistics.median(up_times), 3),
                "upstream_frames": up_counts,
                "upstream_identical_runs": all(d == up_digests[0] for d in up_digests),
            }
            report.append(row)
            print(json.dumps(row))
        browser.close()
    engine.close()
    print(json.dumps({"visphy_median_s": statistics.median(r["visphy_s"] for r in report),
                      "upstream_median_s": statistics.median(r["upstream_s"] for r in report)}))


if __name__ == "__main__":
    main()
