"""Reference descriptions: one text per scene that the text metrics compare each analysis with.

The reference must be the same for every model and must never come from a model's own output
(docs/metrics.md). Two sources (config ``reference``):

* ``spec`` (default, offline): written deterministically from the ground-truth spec and its
  contact events (`describe_spec`). A scene without a spec (the original layout) gets a
  description of its detection context (objects only, no motion), marked as such.
* ``llm``: a configured model describes uniformly sampled **ground-truth** frames (prompt
  ``reference_caption``); it never sees a generated frame.

Either way the text is cached at the dataset level (cache kind ``reference``, keyed by the scene's
ground truth and the source's identity), so every run and every model reads the same text.
"""

from __future__ import annotations

import hashlib
import math
from typing import Any

from visphy_core.api.scene import Scene
from visphy_core.infra.cache import Cache, content_key, read_json

#: Bump when `describe_spec` changes: part of the cache key.
SPEC_DESCRIBER_VERSION = "1"


def _names(ids: list[str]) -> str:
    ids = [i.replace("_", " ") for i in ids]
    if len(ids) <= 1:
        return "".join(ids)
    return ", ".join(ids[:-1]) + " and " + ids[-1]


def _speed(body: dict) -> float:
    v = body.get("velocity") or {}
    if "linear_m_s" in v:
        return math.sqrt(sum(float(c) ** 2 for c in v["linear_m_s"]))
    return math.hypot(float(v.get("vx_px_s", 0.0)), float(v.get("vy_px_s", 0.0)))


def _count(n: int) -> str:
    return f"{n} object" if n == 1 else f"{n} objects"


def describe_spec(spec: dict) -> str:
    """A plain-English motion description from a ground-truth spec and its contact events."""
    bodies = spec.get("bodies", [])
    moving = [b["id"] for b in bodies if b.get("dynamic")]
    fixed = [b["id"] for b in bodies if not b.get("dynamic")]
    launched = [b["id"] for b in bodies if b.get("dynamic") and _speed(b) > 1e-6]
    gravity = spec.get("world", {}).get("gravity_m_s2", [0.0, -9.8])
    g = math.sqrt(sum(float(c) ** 2 for c in gravity))
    sentences = [f"The scene contains {_count(len(bodies))}: "
                 f"{_names([b['id'] for b in bodies])}."]
    if moving:
        sentences.append(f"The dynamic {'body is' if len(moving) == 1 else 'bodies are'} "
                         f"{_names(moving)}; "
                         f"{_names(fixed) or 'nothing'} {'stays' if len(fixed) == 1 else 'stay'} "
                         "fixed.")
    else:
        sentences.append("Every object is fixed, so nothing moves.")
    if launched:
        rest = [m for m in moving if m not in launched]
        sentences.append(f"{_names(launched).capitalize()} "
                         f"{'starts' if len(launched) == 1 else 'start'} with an initial velocity"
                         + (f" while {_names(rest)} {'starts' if len(rest) == 1 else 'start'} "
                            "at rest." if rest else "."))
    elif moving:
        sentences.append("All dynamic bodies start at rest.")
    if moving:
        sentences.append(f"Gravity of {g:.3g} m/s² pulls the dynamic bodies down.")
    pairs: list[str] = []
    first_t: float | None = None
    for ev in spec.get("ground_truth", {}).get("events", []):
        if ev.get("type") != "contact_begin":
            continue
        pair = f"{ev['a'].replace('_', ' ')} and {ev['b'].replace('_', ' ')}"
        if pair not in pairs:
            pairs.append(pair)
            first_t = ev.get("t_s") if first_t is None else first_t
    if pairs:
        when = f" (the first after {float(first_t):.1f} s)" if first_t is not None else ""
        sentences.append(f"Collisions occur between {'; '.join(pairs[:6])}{when}.")
    elif moving:
        sentences.append("The moving bodies touch nothing while the clip lasts.")
    if moving:
        sentences.append("Friction and restitution at the contacts slow the bodies until they "
                         "settle.")
    return " ".join(sentences)


def describe_detection(detection: dict) -> str:
    """Objects only (the original layout has no ground-truth motion in machine form)."""
    objects = detection.get("objects", [])
    kinds = [f"{o.get('id', '?').replace('_', ' ')} ({o.get('category', 'object')})"
             for o in objects]
    return (f"The scene contains {_count(len(objects))}: {', '.join(kinds)}."
            if objects else "The scene contains no detected objects.")


def _ground_truth_key(scene: Scene) -> str:
    h = hashlib.sha256()
    has_spec = scene.spec_path is not None and scene.spec_path.is_file()
    # what a description is made from: the spec, else the detection file; and the video
    for path in (scene.spec_path if has_spec else scene.detection_path, scene.video_path):
        if path is not None and path.is_file():
            h.update(hashlib.sha256(path.read_bytes()).digest())
    return h.hexdigest()


class ReferenceWriter:
    """Reference descriptions of the run's source, cached at the dataset level."""

    def __init__(self, cfg: Any, cache: Cache, model: Any = None, caller: Any = None):
        self.source = str(cfg.source)
        self.frames = int(cfg.get("frames", 8))
        self.cache = cache
        self.model = model       # source=llm: the captioning Model
        self.caller = caller     # its ModelCaller (ledger stage "reference", cost cap)

    def identity(self) -> str:
        if self.source == "llm" and self.model is not None:
            return f"llm:{self.model.identity()}:{self.frames}"
        return f"spec:{SPEC_DESCRIBER_VERSION}"

    def describe(self, scene: Scene) -> tuple[str, str]:
        """(text, how it was made) for one scene."""
        key = content_key("reference", self.identity(), _ground_truth_key(scene))
        hit = self.cache.load("reference", key, lambda e: read_json(e / "reference.json"))
        if hit is not None:
            return str(hit["text"]), str(hit["source"])
        text, source = self._write(scene)
        self.cache.put("reference", key, {"reference.json": _json({"text": text,
                                                                    "source": source})})
        return text, source

    def _write(self, scene: Scene) -> tuple[str, str]:
        if self.source == "llm":
            return self._caption(scene), f"llm:{self.model.name}"
        if scene.spec is not None:
            return describe_spec(scene.spec), "spec"
        if scene.detection is not None:
            return describe_detection(scene.detection), "detection"
        return "", "none"

    def _caption(self, scene: Scene) -> str:
        from visphy_core.api.judge import uniform_indices
        from visphy_core.api.model import ImageInput, ModelRequest, OutputContract
        from visphy_core.calls.prompts.build import png_bytes, reference_caption_prompt

        frames = scene.reference_frames()
        picks = uniform_indices(len(frames), self.frames)
        prompt, version = reference_caption_prompt(len(picks), scene.clip.n_frames /
                                                   scene.clip.fps)
        c = scene.clip
        request = ModelRequest(
            scene_id=scene.scene_id, prompt=prompt, detection=None, engine_name="",
            language="text", output=OutputContract(c.fps, c.n_frames, c.width, c.height),
            images=[ImageInput(f"frame_{i + 1:02d}", png_bytes(frames[i])) for i in picks],
            prompt_version=version, stage="reference")
        response, _ = self.caller.call(request)
        if response.error:
            raise RuntimeError(f"reference description by {self.model.name} failed: "
                               f"{response.error}")
        return response.text.strip()


def _json(data: dict) -> str:
    import json

    return json.dumps(data, sort_keys=True)
