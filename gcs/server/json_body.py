"""The bytes of every REST answer: strict JSON (gcs.core.strict_json), UTF-8, compact.

A non-finite number is null, never an invalid `NaN` token; a lone surrogate (from a \\ud800
escape in a request) cannot be UTF-8 and becomes "?". The routes' response class and the answers
encoded ahead of their requests (gcs.server.polled_answers) both use it, so their bytes agree."""

from __future__ import annotations

from typing import Any

from gcs.core import strict_json


def encode(content: Any) -> bytes:
    return strict_json.dumps(content, ensure_ascii=False, separators=(",", ":")).encode(errors="replace")
