"""A fake OpenAI Videos API (Sora): create, retrieve, download.

* ``POST /v1/videos`` (multipart: ``prompt``, ``model``, ``seconds``, ``size``,
  ``input_reference``; the scripted request, so ``status(429)`` and the other behaviours of
  `FakeProviderServer` apply to it) → a video job, ``status: queued``;
* ``GET /v1/videos/{id}`` → ``in_progress`` for the first `polls_before_done` polls, then
  ``completed``, or ``failed`` with ``error: {code, message}`` when `fail_with` is set;
* ``GET /v1/videos/{id}/content`` → `video` (MP4 bytes).

Requests without ``Authorization: Bearer ...`` are answered 401. `form(req)` parses what the SDK
sent (field name → bytes) so tests can look at the uploaded key frame.
"""

from __future__ import annotations

import itertools
import re
import time
from email.parser import BytesParser
from email.policy import HTTP

from visphy_plugins.testing.fake_server import FakeProviderServer, Recorded
from visphy_plugins.testing.fake_veo import sample_video

JOB = re.compile(r"^/v1/videos/(?P<id>[^/]+)$")
CONTENT = re.compile(r"^/v1/videos/(?P<id>[^/]+)/content$")


def form(req: Recorded) -> dict[str, bytes]:
    """The multipart form of a recorded request: field name → raw value."""
    head = f"Content-Type: {req.headers.get('content-type', '')}\r\n\r\n".encode()
    message = BytesParser(policy=HTTP).parsebytes(head + req.body)
    fields: dict[str, bytes] = {}
    for part in message.iter_parts():
        name = part.get_param("name", header="content-disposition")
        if name:
            fields[str(name)] = part.get_payload(decode=True) or b""
    return fields


class FakeSoraServer(FakeProviderServer):
    """`FakeProviderServer` speaking OpenAI's Videos API."""

    name = "sora"

    def __init__(self, video: bytes | None = None, polls_before_done: int = 2, **kwargs):
        super().__init__(**kwargs)
        self.video = video if video is not None else sample_video()
        self.polls_before_done = polls_before_done
        self.fail_with: tuple[str, str] | None = None       # (code, message)
        self.jobs: dict[str, dict] = {}
        self._ids = itertools.count(1)

    def handles(self, req: Recorded) -> bool:
        return req.method == "POST" and req.path == "/v1/videos"

    def _job(self, vid: str, status: str, progress: int) -> dict:
        job = self.jobs[vid]
        body = {"id": vid, "object": "video", "created_at": job["created_at"],
                "model": job["model"], "progress": progress, "seconds": job["seconds"],
                "size": job["size"], "status": status, "prompt": job["prompt"]}
        if status == "completed":
            body["completed_at"] = int(time.time())
        return body

    def ok_body(self, req: Recorded, text: str, usage: dict[str, int]) -> dict:
        fields = form(req)
        vid = f"video_{next(self._ids)}"
        self.jobs[vid] = {"model": fields.get("model", b"sora-2").decode(),
                          "seconds": fields.get("seconds", b"4").decode(),
                          "size": fields.get("size", b"720x1280").decode(),
                          "prompt": fields.get("prompt", b"").decode(),
                          "created_at": int(time.time()), "polls": 0}
        return self._job(vid, "queued", 0)

    def truncated_body(self, req: Recorded, text: str) -> dict:
        return self.ok_body(req, text, {})

    def empty_body(self, req: Recorded) -> dict:
        return {}

    def refusal_body(self, req: Recorded, text: str) -> dict:
        return {"error": {"code": "moderation_blocked", "message": text,
                          "type": "invalid_request_error"}}

    def other(self, req: Recorded) -> tuple[int, dict | bytes, dict[str, str]] | None:
        if not req.headers.get("authorization", "").startswith("Bearer "):
            return 401, self.error_body(401, "missing API key"), {}
        if req.method != "GET":
            return None
        m = CONTENT.match(req.path)
        if m:
            if m.group("id") not in self.jobs:
                return 404, self.error_body(404, "no such video"), {}
            return 200, self.video, {"content-type": "video/mp4"}
        m = JOB.match(req.path)
        if m:
            vid = m.group("id")
            if vid not in self.jobs:
                return 404, self.error_body(404, "no such video"), {}
            self.jobs[vid]["polls"] += 1
            if self.jobs[vid]["polls"] <= self.polls_before_done:
                return 200, self._job(vid, "in_progress", 50), {}
            if self.fail_with is not None:
                code, message = self.fail_with
                body = self._job(vid, "failed", 100)
                body["error"] = {"code": code, "message": message}
                return 200, body, {}
            return 200, self._job(vid, "completed", 100), {}
        return None
