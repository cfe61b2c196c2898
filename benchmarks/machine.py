"""The machine a benchmark ran on, recorded beside every result: CPU model, SIMD flags, cores,
memory, and the figures of a calibration script when one is at hand (``$VISPHY_CALIBRATE``, or
``../shared/tools/calibrate.py`` beside the checkout), so timings from machines 2-3x apart in
speed can be set side by side."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SIMD = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512_vnni", "amx_tile")


def _cpuinfo() -> tuple[str, list[str]]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or "?", []
    model, flags = "?", []
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "model name" and model == "?":
            model = value.strip()
        elif key.strip() == "flags" and not flags:
            flags = value.split()
    return model, [f for f in SIMD if f in flags]


def _calibration() -> dict | None:
    script = os.environ.get("VISPHY_CALIBRATE") or str(REPO.parent / "shared" / "tools"
                                                       / "calibrate.py")
    if not Path(script).is_file():
        return None
    try:
        out = subprocess.run([sys.executable, script], capture_output=True, text=True,
                             timeout=300)
        return json.loads(out.stdout.strip().splitlines()[-1])
    except (OSError, subprocess.SubprocessError, ValueError, IndexError):
        return None


def _memory_gib() -> float:
    try:
        return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError):
        return float("nan")


def machine_info() -> dict:
    """Cheap, for the start and the end of a timing: CPU model, cores (and those this process
    may use), load average (the machine may be shared), memory in GiB, Python."""
    return {"cores": os.cpu_count(), "usable_cores": len(os.sched_getaffinity(0)),
            "cpu": _cpuinfo()[0], "load_avg": [round(x, 2) for x in os.getloadavg()],
            "memory_gib": _memory_gib(), "python": platform.python_version()}


def machine() -> dict:
    """What the benchmark ran on: `machine_info` with the `SIMD` flags present and the
    calibration figures (which take a few seconds to measure)."""
    return {**machine_info(), "simd": _cpuinfo()[1], "calibration": _calibration()}


if __name__ == "__main__":
    print(json.dumps(machine(), indent=1))
