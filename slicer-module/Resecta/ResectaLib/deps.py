"""The Python packages the module needs, installed on first use, never at import time.

`missing()` lists what is not importable; `ensure_installed(confirm)` asks `confirm(list)` (in
Slicer: `slicer.util.confirmOkCancelDisplay`, a visible prompt) and then installs with
`slicer.util.pip_install`. `resecta_client` comes from the repository's `clients/python` when
the module runs from a checkout (or the folder in the `RESECTA_CLIENT_PATH` environment
variable), else from the package index as `resecta-client`.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Callable

HERE = Path(__file__).resolve().parent
REQUIREMENTS = HERE.parent / "Resources" / "requirements.txt"

#: import name → pip requirement
PACKAGES = {
    "grpc": "grpcio==1.85.3",
    "google.protobuf": "protobuf==7.36.2",
    "numpy": "numpy",
    "resecta_client": "resecta-client",
}


def _importable(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def client_source() -> str:
    """What pip installs for `resecta_client`: a local folder when there is one."""
    env = os.environ.get("RESECTA_CLIENT_PATH")
    if env and Path(env, "pyproject.toml").is_file():
        return env
    for base in (HERE.parents[2], HERE.parents[1]):  # <repo>/slicer-module/Resecta/ResectaLib
        candidate = base / "clients" / "python"
        if (candidate / "pyproject.toml").is_file():
            return str(candidate)
    return PACKAGES["resecta_client"]


def missing() -> list[str]:
    """pip requirements of the packages that are not importable."""
    out = []
    for module, requirement in PACKAGES.items():
        if not _importable(module):
            out.append(client_source() if module == "resecta_client" else requirement)
    return out


def ensure_installed(confirm: Callable[[list[str]], bool]) -> bool:
    """True when everything is importable (installing after `confirm` said yes)."""
    needed = missing()
    if not needed:
        return True
    if not confirm(needed):
        return False
    import slicer  # only inside Slicer: pip_install is a Slicer helper

    for requirement in needed:
        slicer.util.pip_install(requirement)
    importlib.invalidate_caches()
    return not missing()
