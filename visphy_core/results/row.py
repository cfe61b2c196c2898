"""One row of a run: a scene's outcome as `SceneResult`, and how it is stored.

A row is written to ``results.jsonl`` as the scene finishes (`visphy_core.results.run_dir`) and
to ``results.parquet`` when the run ends. List and dict fields (`JSON_COLUMNS`, ``unavailable``)
are stored as JSON text; each score is a column ``score_<name>`` (`visphy_core.results.columns`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

from visphy_core.api.engine import FailureClass
from visphy_core.results.columns import SCORE


@dataclass
class SceneResult:
    """One row of results.parquet."""

    scene_id: str
    dim: str
    difficulty: str | None
    model_success: bool = False    # the model's own program (first or repaired) gave a clip
    system_success: bool = False   # a clip exists, counting the fallback
    fallback: bool = False
    attempts: int = 0
    failure_class: str | None = None     # why the last model attempt failed (None on success)
    failure_detail: str | None = None
    first_failure_class: str | None = None  # why the first attempt failed (retry ablation)
    flags: list[str] = field(default_factory=list)
    response_cached: bool = False
    render_cached: bool = False
    render_wall_s: float | None = None
    model_latency_s: float = 0.0
    # seconds of wall time in the score stage (reference-program renders inside it excluded:
    # they are ``reference_render_wall_s``) and in the judge stage; None: the stage did not run
    # (``scoring_``, not ``score_``: every ``score_*`` column of a row is a score)
    scoring_wall_s: float | None = None
    reference_render_wall_s: float | None = None
    judge_wall_s: float | None = None
    cost_usd: float = 0.0
    model_calls: int = 0                 # calls actually sent to the model (cache misses)
    infra_retries: int = 0               # renders repeated after an infra_error
    isolation: str | None = None         # how the program was isolated (RenderResult.isolation)
    prompt_version: str | None = None    # templates the first prompt was built from
    output_kind: str = "program"         # program (rendered) or video (a pixel-space model)
    finish_reason: str | None = None     # the provider's reason the last reply ended
    input_tokens: int = 0                # over the replies used (cached ones included)
    output_tokens: int = 0
    spec_valid: bool | None = None       # the reply's S against the ground truth's schema
    spec_problems: list[str] = field(default_factory=list)
    reference_source: str | None = None  # how the reference description was made
    spec_track: str | None = None        # S simulated and replayed: rendered, no_spec,
    spec_track_error: str | None = None  # invalid_spec or failed (why); None: track off
    judge_errors: dict[str, str] = field(default_factory=dict)  # invalid verdicts, why
    frame_digests: list[str] = field(default_factory=list)
    scores: dict[str, float | None] = field(default_factory=dict)
    unavailable: dict[str, str] = field(default_factory=dict)

    @property
    def evaluable(self) -> bool:
        """False when the scene could not be evaluated through no fault of the model
        (``infra_error``: our side failed; ``data_error``: a bad input of the scene)."""
        return self.failure_class not in NOT_EVALUABLE

    @property
    def outcome(self) -> str:
        """The outcome in a word or two, as the console's table and MLflow's scene table say
        it: ``ok``, ``repaired``, ``fallback (<class>)`` or ``failed (<class>)``."""
        if self.model_success:
            return "ok" if self.attempts == 1 else "repaired"
        return f"{'fallback' if self.fallback else 'failed'} ({self.failure_class})"

    def row(self) -> dict:
        d = asdict(self)
        scores = d.pop("scores")
        d["unavailable"] = json.dumps(self.unavailable, sort_keys=True)
        d["flags"] = ",".join(self.flags)
        for name in JSON_COLUMNS:
            d[name] = json.dumps(d[name], sort_keys=True)
        for name, value in scores.items():
            d[SCORE + name] = value
        return d

    @classmethod
    def from_row(cls, row: dict) -> "SceneResult":
        """Inverse of `row` (a resumed run reads its finished scenes back from results.jsonl).
        A row written by an older version may lack fields: they take their defaults (``dim``
        and ``difficulty``: None)."""
        d = {"dim": None, "difficulty": None, **row}
        scores = {k[len(SCORE):]: d.pop(k) for k in list(d) if k.startswith(SCORE)}
        known = {f for f in cls.__dataclass_fields__}
        d = {k: v for k, v in d.items() if k in known}
        d["flags"] = [f for f in (d.get("flags") or "").split(",") if f]
        for name in (*JSON_COLUMNS, "unavailable"):
            if isinstance(d.get(name), str):
                d[name] = json.loads(d[name])
            elif name in d and d[name] is None:
                del d[name]
        return cls(**d, scores=scores)


#: List/dict fields stored as JSON text in results.jsonl and results.parquet.
JSON_COLUMNS = ("frame_digests", "spec_problems", "judge_errors")
#: Failure classes that say nothing about the model: not counted against it.
NOT_EVALUABLE = (FailureClass.INFRA_ERROR.value, FailureClass.DATA_ERROR.value)
