"""A fake Gemini API for Veo: the long-running video operation and the file download.

* ``POST /{version}/models/{model}:predictLongRunning`` (the scripted request: ``status(429)``
  and the other behaviours of `FakeProviderServer` apply to it) → ``{"name":
  "models/{model}/operations/{id}"}``;
* ``GET /{version}/models/{model}/operations/{id}`` (also ``/{version}/operations/{id}``) →
  not done for the first `polls_before_done` polls, then ``done`` with
  ``response.generateVideoResponse.generatedSamples[0].video.uri`` (a
  ``https://generativelanguage.googleapis.com/.../files/{id}:download?alt=media`` URI, as the
  real API gives; the SDK turns it into a download from its own base URL), or with ``error``
  (`fail_with`), or with only ``raiMediaFilteredCount``/``Reasons`` (`filter_reasons`);
* ``GET /{version}/files/{id}:download?alt=media`` → `video` (MP4 bytes).

Every request without an ``x-goog-api-key`` header is answered 403, as the real API does.
"""

from __future__ import annotations

import itertools
import re

from visphy_plugins.testing.fake_server import FakeProviderServer, Recorded

CREATE = re.compile(r"^/(?P<version>[^/]+)/models/(?P<model>[^/:]+):predictLongRunning$")
OPERATION = re.compile(r"^/(?P<version>[^/]+)/(?:models/[^/:]+/)?operations/(?P<op>[^/:]+)$")
DOWNLOAD = re.compile(r"^/(?P<version>[^/]+)/files/(?P<file>[^/:]+):download$")

STATUS_NAMES = {400: "INVALID_ARGUMENT", 401: "UNAUTHENTICATED", 403: "PERMISSION_DENIED",
                404: "NOT_FOUND", 429: "RESOURCE_EXHAUSTED", 500: "INTERNAL",
                503: "UNAVAILABLE", 504: "DEADLINE_EXCEEDED"}


def sample_video(fps: float = 24.0, n_frames: int = 8, width: int = 256, height: int = 256
                 ) -> bytes:
    """A real small MP4 (``encode_video``): frame i is flat grey 20 + 30·i."""
    import tempfile
    from pathlib import Path

    import numpy as np

    from visphy_core.api.media import encode_video

    frames = [np.full((height, width, 3), min(255, 20 + 30 * i), np.uint8)
              for i in range(n_frames)]
    with tempfile.TemporaryDirectory() as tmp:
        return encode_video(frames, Path(tmp) / "v.mp4", fps).read_bytes()


class FakeVeoServer(FakeProviderServer):
    """`FakeProviderServer` speaking the Gemini API's Veo operations."""

    name = "veo"

    def __init__(self, video: bytes | None = None, polls_before_done: int = 2, **kwargs):
        super().__init__(**kwargs)
        self.video = video if video is not None else sample_video()
        self.polls_before_done = polls_before_done
        self.fail_with: tuple[int, str] | None = None      # (gRPC code, message)
        self.filter_reasons: list[str] | None = None
        self.operations: dict[str, dict] = {}               # id -> {"model", "polls"}
        self._ids = itertools.count(1)

    # ------------------------------------------------------------------ wire format
    def handles(self, req: Recorded) -> bool:
        return req.method == "POST" and CREATE.match(req.path) is not None

    def error_body(self, code: int, message: str) -> dict:
        return {"error": {"code": code, "message": message,
                          "status": STATUS_NAMES.get(code, "UNKNOWN")}}

    def ok_body(self, req: Recorded, text: str, usage: dict[str, int]) -> dict:
        m = CREATE.match(req.path)
        model = m.group("model") if m else "veo"
        op = f"op{next(self._ids)}"
        self.operations[op] = {"model": model, "polls": 0}
        return {"name": f"models/{model}/operations/{op}"}

    def truncated_body(self, req: Recorded, text: str) -> dict:
        return self.ok_body(req, text, {})

    def empty_body(self, req: Recorded) -> dict:
        return {}

    def refusal_body(self, req: Recorded, text: str) -> dict:
        return self.error_body(400, text or "The prompt violates the usage guidelines.")

    def other(self, req: Recorded) -> tuple[int, dict | bytes, dict[str, str]] | None:
        if not req.headers.get("x-goog-api-key"):
            return 403, self.error_body(403, "Method doesn't allow unregistered callers"), {}
        m = OPERATION.match(req.path)
        if req.method == "GET" and m:
            op = m.group("op")
            state = self.operations.get(op)
            if state is None:
                return 404, self.error_body(404, f"operation {op} not found"), {}
            state["polls"] += 1
            name = f"models/{state['model']}/operations/{op}"
            if state["polls"] <= self.polls_before_done:
                return 200, {"name": name, "metadata": {"@type": "fake.progress"}}, {}
            if self.fail_with is not None:
                code, message = self.fail_with
                return 200, {"name": name, "done": True,
                             "error": {"code": code, "message": message}}, {}
            if self.filter_reasons is not None:
                return 200, {"name": name, "done": True, "response": {
                    "@type": "type.googleapis.com/google.ai.generativelanguage.v1beta."
                             "PredictLongRunningResponse",
                    "generateVideoResponse": {"raiMediaFilteredCount": 1,
                                              "raiMediaFilteredReasons": self.filter_reasons}}}, {}
            uri = (f"https://generativelanguage.googleapis.com/v1beta/files/{op}vid:download"
                   "?alt=media")
            return 200, {"name": name, "done": True, "response": {
                "@type": "type.googleapis.com/google.ai.generativelanguage.v1beta."
                         "PredictLongRunningResponse",
                "generateVideoResponse": {"generatedSamples": [{"video": {"uri": uri}}]}}}, {}
        m = DOWNLOAD.match(req.path)
        if req.method == "GET" and m:
            return 200, self.video, {"content-type": "video/mp4"}
        return None
