"""Plan files (`resecta-plan/1` JSON, the format of `resecta plan` and ExportPlan/ImportPlan)."""

from __future__ import annotations

import json
from pathlib import Path

FORMAT = "resecta-plan/1"


def check(text: str) -> dict:
    """Parses a plan document and checks its envelope (the server checks the rest)."""
    try:
        plan = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not a JSON plan: {exc}") from None
    if not isinstance(plan, dict) or plan.get("format") != FORMAT:
        raise ValueError(f"not a {FORMAT} plan (format: {plan.get('format') if isinstance(plan, dict) else None!r})")
    if not isinstance(plan.get("resections", []), list):
        raise ValueError("the plan's resections are not a list")
    return plan


def save(path: str | Path, plan_json: str) -> Path:
    """Writes the plan (pretty-printed, checked first)."""
    plan = check(plan_json)
    path = Path(path)
    path.write_text(json.dumps(plan, indent=2) + "\n", encoding="utf-8")
    return path


def load(path: str | Path) -> str:
    """Reads and checks a plan file; returns its text for ImportPlan."""
    text = Path(path).read_text(encoding="utf-8")
    check(text)
    return text


def resection_names(plan_json: str) -> list[str]:
    return [r.get("name", "") for r in check(plan_json).get("resections", [])]
