"""Model ``replay``: answers from recorded replies, so a published or earlier run can be
re-rendered and re-scored offline (``model=replay model.source=PATH``).

``source`` may be:

* a visphy run directory (``scenes/<id>/response.txt``, ``response.attempt2.txt`` for the
  repair call, ``reply.mp4`` — the model's own video — for a pixel-space model's run; a call
  that failed at the provider, recorded in ``response.json``, is replayed as that failure):
  replaying it with the same engine and settings reproduces that run's rows;
* a folder with one file per scene: ``<id>.txt`` / ``.md`` / ``.html`` / ``.py`` (a bare program
  without a fence is wrapped in one), ``<id>.attempt2.<ext>`` for a repair reply, ``<id>.mp4`` for
  a video;
* a folder with one sub-folder per scene holding one reply file (``<id>/response.txt`` or the
  only ``.txt``/``.md``/``.html``/``.py`` file in it);
* a single reply file (the ``render`` command uses this: every scene gets that reply).

A scene with no recorded reply is a ``model_error`` naming the file it looked for; a repair call
with no recorded repair reply keeps the first attempt's failure (``error_kind="not_recorded"``).
Replies cost nothing and are not billed again.

The source is a foreign tree: every file is read through `visphy_core.infra.files` (no symbolic link
below ``source`` is followed, only regular files, size caps). A scene whose reply is a link, or
sits in a linked folder, is a ``data_error`` row naming the path; its content is never read.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from omegaconf import MISSING

from visphy_core.api.config_schema import ModelConfig
from visphy_core.api.errors import UserError
from visphy_core.api.extract import fenced_blocks
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.model import Model, ModelRequest, ModelResponse
from visphy_core.api.storage import files
from visphy_core.results import layout
from visphy_core.results.row import SceneResult
from visphy_core.results.rows import parse_lines

TEXT_SUFFIXES = (".txt", ".md", ".html", ".py")
FENCE_FOR = {".html": "html", ".py": "python"}


@dataclass
class ReplayConfig(ModelConfig):
    source: str = MISSING          # a run directory, a folder of replies, or one reply file
    output: Optional[str] = None   # program | video (null: from the run's manifest / files)


class ReplayModel(Model):
    version = "1"

    def __init__(self, cfg):
        super().__init__(cfg)
        self.name = str(cfg.get("name", "replay"))
        self.source = Path(str(cfg.source)).expanduser()
        #: the tree no link is followed below (a single reply file: its folder)
        self.root = self.source if self.source.is_dir() else self.source.parent
        self.output_kind = str(cfg.get("output") or self._detect_output())

    # ------------------------------------------------------------------ layout
    def _is_run_dir(self) -> bool:
        if not hasattr(self, "_run_dir"):
            self._run_dir = self.source.is_dir() \
                and files.entry_kind(self.source / layout.SCENES, self.root) == "dir" \
                and files.is_file(self.source / layout.MANIFEST, self.root)
        return self._run_dir

    def _detect_output(self) -> str:
        if self._is_run_dir():
            try:
                manifest = files.read_json(self.source / layout.MANIFEST, self.root)
                return ((manifest or {}).get("model") or {}).get("output", "program")
            except (OSError, ValueError, AttributeError):
                return "program"
        if self.source.is_dir():
            suffixes = {Path(name).suffix for name, kind in files.list_dir(self.source)
                        if kind == "file"}
            if ".mp4" in suffixes and not suffixes & set(TEXT_SUFFIXES):
                return "video"
        return "program"

    def check_ready(self) -> None:
        if not self.source.exists():
            raise UserError(f"model=replay: model.source={self.source} does not exist (a run "
                            "directory, a folder of replies named <scene_id>.txt, or one reply "
                            "file)")

    def identity(self) -> str:
        """Name plus a digest of every recorded reply: editing a reply file is a new model.
        A link is digested as its name only (its target is never read; the scene that uses it
        becomes a ``data_error`` row)."""
        h = hashlib.sha256()
        for path, kind in self._recorded_files():
            h.update(f"{kind}:{path.relative_to(self.root)}".encode())
            if kind == "file":
                h.update(hashlib.sha256(files.read_bytes(path, self.root, kind="any")).digest())
        return json.dumps(["replay", self.version, self.output_kind, h.hexdigest()])

    def _recorded_files(self) -> list[tuple[Path, str]]:
        """(path, "file" | "link" | "other") of every reply or video under the source, sorted,
        found without following links."""
        if not self.source.is_dir():
            return [(self.source, "file")]
        out: list[tuple[Path, str]] = []
        stack = [self.source]
        while stack:
            folder = stack.pop()
            for name, kind in files.list_dir(folder, self.root):
                path = folder / name
                if kind == "dir":
                    stack.append(path)
                elif path.suffix in TEXT_SUFFIXES or path.suffix == ".mp4":
                    out.append((path, kind))
        return sorted(out)

    def _candidates(self, scene_id: str, attempt: int) -> list[Path]:
        if self.source.is_file():
            return [self.source] if attempt == 1 else []
        tag = layout.attempt_suffix(attempt)
        if self._is_run_dir():
            scene = self.source / layout.SCENES / scene_id
            reply = scene / layout.attempt_file(layout.REPLY, attempt, "mp4")
            if self.output_kind == "video":
                # the model's own video; the scored clip of runs that did not keep it, unless
                # that clip is the fallback (see `_fallback_video`)
                return [reply, scene / layout.VIDEO] if attempt == 1 else [reply]
            return [scene / layout.attempt_file(layout.RESPONSE, attempt, "txt")]
        if self.output_kind == "video":
            return [self.source / f"{scene_id}.mp4"] if attempt == 1 else []
        found = [self.source / f"{scene_id}{tag}{ext}" for ext in TEXT_SUFFIXES]
        folder = self.source / scene_id
        if files.entry_kind(folder, self.root) == "dir":
            found.append(folder / layout.attempt_file(layout.RESPONSE, attempt, "txt"))
            if attempt == 1:
                found += [folder / name for name, _ in files.list_dir(folder, self.root)
                          if Path(name).suffix in TEXT_SUFFIXES and ".attempt" not in name]
        return found

    def _run_rows(self) -> dict[str, SceneResult]:
        """A run directory's result rows by scene id (empty when unreadable)."""
        if not hasattr(self, "_rows"):
            self._rows = {}
            try:
                text = files.read_text(self.source / layout.RESULTS_JSONL, self.root,
                                      kind="jsonl")
            except (OSError, ValueError):
                return self._rows
            self._rows = {r.scene_id: r for r in parse_lines(text)[0]}
        return self._rows

    def _recorded_error(self, scene_id: str, attempt: int) -> Optional[ModelResponse]:
        """In a run directory, the call that failed at the provider (``response.json`` holds
        its error) is replayed as that failure, not as an empty reply."""
        meta = (self.source / layout.SCENES / scene_id
                / layout.attempt_file(layout.RESPONSE, attempt, "json"))
        try:
            if not files.is_file(meta, self.root):
                return None
            recorded = files.read_json(meta, self.root)
        except FileNotFoundError:
            return None
        except files.ForeignFileError:
            raise
        except (OSError, ValueError):
            return None
        if not isinstance(recorded, dict) or not recorded.get("error"):
            return None
        return ModelResponse(text="", error=str(recorded["error"]),
                             error_kind=recorded.get("error_kind") or "server",
                             finish_reason=recorded.get("finish_reason"), cost_usd=0.0)

    def _fallback_video(self, path: Path, scene_id: str) -> bool:
        """An old run directory's ``video.mp4`` that is the fallback clip, not the model's."""
        row = self._run_rows().get(scene_id)
        return path.name == layout.VIDEO and row is not None and row.fallback

    # ------------------------------------------------------------------ replies
    def generate(self, request: ModelRequest) -> ModelResponse:
        if self._is_run_dir():
            failed = self._recorded_error(request.scene_id, request.attempt)
            if failed is not None:
                return failed
        candidates = self._candidates(request.scene_id, request.attempt)
        path = next((p for p in candidates if files.is_file(p, self.root)), None)
        if path is not None and self._is_run_dir() and self._fallback_video(path,
                                                                            request.scene_id):
            return ModelResponse(text="", error=f"the recorded run has no video of its own for "
                                 f"{request.scene_id} (its video.mp4 is the fallback clip)",
                                 error_kind="not_recorded")
        if path is None:
            if request.attempt > 1:
                return ModelResponse(text="", error=f"no recorded reply for attempt "
                                     f"{request.attempt} of {request.scene_id}",
                                     error_kind="not_recorded")
            looked = ", ".join(str(p) for p in candidates) or str(self.source)
            return ModelResponse(text="", error=f"no recorded reply for {request.scene_id} "
                                 f"(looked for {looked})", error_kind="not_recorded")
        if self.output_kind == "video":
            return ModelResponse(text=f"recorded video {path.name}", video_path=str(path),
                                 cost_usd=0.0)
        response = ModelResponse(text=_as_reply(path, self.root), cost_usd=0.0)
        if self._is_run_dir():  # the recorded finish reason and refusal classify it the same
            meta = path.with_suffix(".json")
            try:
                recorded = files.read_json(meta, self.root)
                response.finish_reason = recorded.get("finish_reason")
                response.refusal = recorded.get("refusal")
            except files.ForeignFileError:
                raise
            except (OSError, ValueError, AttributeError):
                pass
        return response


def _as_reply(path: Path, root: Path) -> str:
    """The file's text; a bare program (no fence at all) is wrapped in the fence its suffix
    implies, so recorded programs written elsewhere extract like replies."""
    text = files.read_text(path, root, kind="reply")
    blocks, unclosed = fenced_blocks(text)
    if not blocks and unclosed is None and path.suffix in FENCE_FOR:
        return f"```{FENCE_FOR[path.suffix]}\n{text.rstrip()}\n```\n"
    return text


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="model", name="schema_replay", node=ReplayConfig)


@hookimpl
def visphy_register_models(register):
    register("replay", ReplayModel)
