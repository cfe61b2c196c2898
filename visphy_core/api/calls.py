"""Calling a provider, for model and judge plugins: classified errors with retries and adaptive
concurrency (`visphy_core.calls.retry`), API keys (`visphy_core.calls.keys`), secret redaction
(`visphy_core.infra.secrets`), prices (`visphy_core.calls.usage`), the judge prompt and the
reference description of a scene."""

from __future__ import annotations

from visphy_core.calls.keys import require_key
from visphy_core.calls.prompts.build import judge_prompt
from visphy_core.calls.references import describe_spec
from visphy_core.calls.retry import (
    CallError,
    CallErrorKind,
    RetryPolicy,
    call_with_retries,
    kind_for_status,
    limiter_for,
    retry_after_seconds,
)
from visphy_core.calls.usage import Price
from visphy_core.infra.secrets import redact, redact_obj

__all__ = [
    "call_with_retries", "CallError", "CallErrorKind", "describe_spec", "judge_prompt",
    "kind_for_status", "limiter_for", "Price", "redact", "redact_obj", "require_key",
    "retry_after_seconds", "RetryPolicy",
]
