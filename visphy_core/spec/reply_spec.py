"""Validate the scene specification S a model writes, against the ground truth's schema.

An invalid S is recorded (``spec_valid = false`` and the first problems with their JSON paths),
never fatal: the program is still rendered and scored.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import jsonschema

from visphy_core.spec.validation import json_path


@lru_cache(maxsize=2)
def _validator(dim: str) -> jsonschema.protocols.Validator:
    if dim == "3d":
        from visphy_core.spec.spec3d import REPLY_SCHEMA_3D as schema
    else:
        from visphy_core.spec.spec2d import REPLY_SCHEMA_2D as schema
    return jsonschema.Draft202012Validator(schema)


def spec_problems(spec: Any, dim: str, limit: int = 5) -> list[str]:
    """Up to ``limit`` problems of S as ``<json path>: <message>`` (empty when S is valid)."""
    if not isinstance(spec, dict):
        return [f"$: S is a {type(spec).__name__}, not a JSON object"]
    problems = []
    for err in sorted(_validator(dim).iter_errors(spec), key=lambda e: list(e.absolute_path)):
        while err.context:  # descend into if/then/allOf to the concrete failure
            err = jsonschema.exceptions.best_match(err.context)
        problems.append(f"{json_path(err.absolute_path)}: {' '.join(err.message.split())[:200]}")
        if len(problems) >= limit:
            break
    return problems
