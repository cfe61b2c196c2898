"""The render contract every engine plugin meets, and the failure classes it reports.

An engine turns a model's reply into a `Program`, checks it, and runs it to exactly the frames the
reference clip has (same fps, frame count and size), in virtual time. Engines never raise for a
bad program: a bad program is a `RenderResult` with a failure class, so the run goes on.
"""

from __future__ import annotations

import hashlib
import json
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from visphy_core.api.scene import Scene
from visphy_core.infra.js_assets import JsAssets


class FailureClass(str, Enum):
    """Why a scene produced no usable clip (docs/running.md)."""

    NO_CODE = "no_code"
    TRUNCATED = "truncated"
    WRONG_LANGUAGE = "wrong_language"
    SYNTAX_ERROR = "syntax_error"
    RUNTIME_ERROR = "runtime_error"
    TIMEOUT = "timeout"
    BLANK_OUTPUT = "blank_output"
    STATIC_OUTPUT = "static_output"
    SANDBOX_VIOLATION = "sandbox_violation"
    RESOURCE_LIMIT = "resource_limit"   # the program hit a memory, disk, file-size or process cap
    INFRA_ERROR = "infra_error"         # our side failed (browser crash, missing renderer)
    REFUSAL = "refusal"                 # the model refused (its provider's refusal signal)
    MODEL_ERROR = "model_error"         # the provider failed after retries
    DATA_ERROR = "data_error"           # a bad input of this scene (detection JSON, GT video)

    @property
    def blames_program(self) -> bool:
        """True when the model's program is at fault (a repair call may help). A refusal is
        the model's failure but asking again with an error summary is not a repair."""
        return self not in (FailureClass.INFRA_ERROR, FailureClass.MODEL_ERROR,
                            FailureClass.DATA_ERROR, FailureClass.REFUSAL)


class RenderFlag(str, Enum):
    """Observations about a render that are not failures: recorded in the row's ``flags`` (and
    the scene's render log) so that what the engine did to the program stays visible."""

    #: A library URL the program asked for was served from a vendored copy of another version
    #: (the render log names each requested URL/version and the file/version served instead).
    LIBRARY_SUBSTITUTED = "library_substituted"
    #: The program never made the recording call its engine's instructions ask for (browser
    #: engines whose instructions ask for ``setupRecording(canvas, durationMs)``). Frames are
    #: still captured: the clock is virtual, so the call only names the canvas and the length.
    NO_RECORDING_CALL = "no_recording_call"
    #: The program's canvas or camera frame does not have the clip's size, so it was scaled to
    #: fit (uniformly, centred, background-coloured bars where the aspect ratios differ).
    CANVAS_RESIZED = "canvas_resized"
    #: A runtime error came after some frames were captured: those frames are kept as an
    #: artifact (``partial.mp4``); the failure class stays ``runtime_error``.
    PARTIAL_CLIP = "partial_clip"


class ProgramRejected(Exception):
    """Extraction or validation refused a reply; carries the failure class."""

    def __init__(self, failure: FailureClass, message: str):
        super().__init__(message)
        self.failure = failure


@dataclass(frozen=True)
class Program:
    """One executable program as the engine will run it (before the trusted template is added)."""

    language: str
    source: str
    spec: dict | None = None  # the reply's JSON scene specification S, when it had one

    @property
    def digest(self) -> str:
        return hashlib.sha256(f"{self.language}\n{self.source}".encode()).hexdigest()


@dataclass(frozen=True)
class RenderContract:
    """The reference clip's shape: what the render must produce, frame for frame."""

    fps: float
    n_frames: int
    width: int
    height: int
    dim: str = "2d"
    timeout_s: float = 60.0
    seed: int = 0

    @classmethod
    def for_scene(cls, scene: Scene, timeout_s: float = 60.0, seed: int = 0) -> "RenderContract":
        c = scene.clip
        return cls(fps=c.fps, n_frames=c.n_frames, width=c.width, height=c.height, dim=scene.dim,
                   timeout_s=timeout_s, seed=seed)

    def frame_times_ms(self) -> list[float]:
        """Virtual capture times: frame k at k / fps seconds (frame 0 at t = 0)."""
        return [1000.0 * k / self.fps for k in range(self.n_frames)]

    def key(self) -> str:
        """Cache key part: everything that changes the frames (the time limit does not)."""
        d = asdict(self)
        d.pop("timeout_s")
        return json.dumps(d, sort_keys=True)


@dataclass
class RenderResult:
    """Frames (N×H×W×3 uint8) or a failure, plus the evidence needed to explain it."""

    frames: np.ndarray | None
    failure: FailureClass | None = None
    error: str | None = None
    logs: list[str] = field(default_factory=list)
    blocked_requests: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    #: How the program was isolated, e.g. "bwrap:uid65534,netns,pidns" or "browser:netns";
    #: "none" when it ran unisolated (explicit opt-out). Recorded in every result row.
    isolation: str | None = None
    #: `RenderFlag` values (strings) observed during the render, successful or not.
    flags: list[str] = field(default_factory=list)
    #: With ``partial_clip``: the clip-sized frames captured before a runtime error (N×H×W×3).
    partial_frames: np.ndarray | None = None

    def flag(self, flag: "RenderFlag") -> None:
        """Record ``flag`` once."""
        if flag.value not in self.flags:
            self.flags.append(flag.value)

    @property
    def ok(self) -> bool:
        return self.failure is None and self.frames is not None


class Engine(ABC):
    """Base class for engine plugins (the built-in ones are in ``plugins/engines/``)."""

    name: str = ""
    language: str = ""   # fence language the prompt asks for: "html" or "python"
    version: str = "0"   # bump when rendering changes: part of every cache key
    supports_3d: bool = False
    #: The npm packages the engine's pages load (`visphy_core.api.assets`): ``visphy setup``
    #: installs those of every registered engine class. None: the engine vendors nothing.
    js_assets: JsAssets | None = None
    #: The paper's published success rates for the engine (first attempt, after one retry),
    #: shown beside a run's in the retry table (`visphy_core.analysis.retry`); None: not
    #: reported.
    paper_retry: tuple[float, float] | None = None

    def __init__(self, cfg: Any = None):
        self.cfg = cfg

    def instructions(self, dim: str) -> str:
        """Engine-specific part of the prompt for a 2D or 3D scene."""
        return ""

    @abstractmethod
    def extract(self, text: str) -> Program:
        """Program from a model reply; raises `ProgramRejected` (no_code, truncated, ...)."""

    @abstractmethod
    def validate(self, program: Program) -> None:
        """Static checks before running; raises `ProgramRejected`."""

    @abstractmethod
    def render(self, program: Program, contract: RenderContract) -> RenderResult:
        """Run the program in the sandbox and capture exactly ``contract.n_frames`` frames."""

    @abstractmethod
    def program_from_spec(self, scene: Scene) -> Program:
        """A trusted reference program for a ground-truth scene (a privileged model's answer,
        the spec track, conformance checks)."""

    def native_program_from_spec(self, scene: Scene) -> Program:
        """Optional: a trusted reference program that draws the same ground truth with the
        engine's own primitives and default anti-aliasing, as a correct model program would
        (a privileged model's ``model.style=native``: the engine's intrinsic ceiling). Raises
        ``NotImplementedError`` where the engine has none (the default)."""
        raise NotImplementedError(f"the {self.name} engine has no native reference program")

    def close(self) -> None:
        """Release pooled resources (browsers, child processes)."""

    def cache_identity(self) -> str:
        return f"{self.name}@{self.version}"


def classify_frames(frames: np.ndarray) -> FailureClass | None:
    """blank_output when every frame is one flat colour; static_output when nothing ever moves.

    A blank clip is a failure (there is nothing to score); a static clip is still scored, the
    pipeline records the class as a flag so "no motion when motion was expected" stays visible.
    """
    # The first frame alone settles most clips (the whole clip is 75 × 512² pixels for 3D).
    if np.all(frames[0] == frames[0, 0, 0]) and np.all(frames == frames[0, 0, 0]):
        return FailureClass.BLANK_OUTPUT
    if len(frames) > 1 and all(np.array_equal(frames[0], f) for f in frames[1:]):
        return FailureClass.STATIC_OUTPUT
    return None
