"""End-to-end tests run the real `resecta` binary (RESECTA_BIN, default target/debug/resecta)."""
import json
import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TEST_DATA = ROOT.parent / "shared" / "test-data"


def resecta_bin() -> str:
    return os.environ.get("RESECTA_BIN", str(ROOT / "target" / "debug" / "resecta"))


class Run:
    def __init__(self, proc: subprocess.CompletedProcess):
        self.code = proc.returncode
        self.stdout = proc.stdout
        self.stderr = proc.stderr

    def json(self):
        # Exactly one JSON object on stdout: json.loads fails on anything else.
        obj = json.loads(self.stdout)
        assert isinstance(obj, dict)
        return obj


@pytest.fixture
def resecta():
    def run(*args, check=True) -> Run:
        proc = subprocess.run([resecta_bin(), *map(str, args)], capture_output=True, text=True,
                              timeout=600)
        r = Run(proc)
        if check and r.code != 0:
            raise AssertionError(f"resecta {args} exited {r.code}: {r.stderr}")
        return r
    return run


@pytest.fixture
def test_data():
    if not TEST_DATA.is_dir():
        print(f"SKIP: real test data not found at {TEST_DATA}")
        pytest.skip(f"real test data not found at {TEST_DATA}")
    return TEST_DATA
