"""Drift check: the committed stubs in resecta_client/_gen are exactly what
scripts/generate_stubs.py makes from proto/ now."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "generate_stubs.py"


def test_committed_stubs_match_the_protos(tmp_path: Path) -> None:
    pytest.importorskip("grpc_tools", reason="grpcio-tools is needed to regenerate the stubs")
    spec = importlib.util.spec_from_file_location("generate_stubs", SCRIPT)
    assert spec is not None and spec.loader is not None
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    fresh = {p.name: p.read_text() for p in gen.generate(tmp_path / "_gen")}
    committed = {p.name: p.read_text() for p in sorted(gen.GEN.iterdir()) if p.is_file()}
    stale = sorted(n for n in fresh.keys() | committed.keys() if fresh.get(n) != committed.get(n))
    assert not stale, (
        f"the generated stubs in {gen.GEN} differ from proto/ in {stale}: run "
        "`python clients/python/scripts/generate_stubs.py` and commit the result"
    )
    assert not any("from resecta.v1" in text or "import resecta." in text for text in fresh.values())
