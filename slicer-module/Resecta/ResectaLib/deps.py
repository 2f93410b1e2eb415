"""What the module needs from its Python: a supported Slicer, the resecta client, and three
packages installed on first use — never at import time.

- `check_slicer_version(version)`: Resecta runs on 3D Slicer 5.10 or newer (Python 3.12). The
  client's generated stubs need protobuf >= 7.35.1 and grpcio >= 1.85.1, which have no wheels for
  the Python 3.9 of Slicer 5.8 and older; `UnsupportedSlicer` says so.
- `use_client()`: the client package `resecta_client` is shipped inside the module
  (`Resources/Python`, copied there from `clients/python/src` by the CMake build) or, in a
  checkout, taken from `<repo>/clients/python/src`; that folder goes first on `sys.path`. It is
  never installed with pip.
- `ensure_installed(confirm)`: grpcio, protobuf and numpy, with the version ranges of
  `Resources/requirements.txt` (the one list). A package inside its range is kept, a missing or
  older one is installed or upgraded with Slicer's `pip_install` (one argument per requirement)
  after `confirm(lines)` said yes; one newer than the range allows raises `DependencyConflict` —
  other extensions share these packages, so Resecta never downgrades them.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
MODULE_DIR = HERE.parent
REQUIREMENTS = MODULE_DIR / "Resources" / "requirements.txt"
#: Where the extension's build puts the client (Resecta/CMakeLists.txt, RESECTA_CLIENT_SUBDIR).
BUNDLED_CLIENT = MODULE_DIR / "Resources" / "Python"
#: The client in a checkout: <repo>/slicer-module/Resecta/ResectaLib → <repo>/clients/python/src.
CHECKOUT_CLIENT = HERE.parents[2] / "clients" / "python" / "src"

MIN_SLICER = (5, 10)
MIN_PYTHON = (3, 11)  # clients/python/pyproject.toml requires-python; Slicer 5.10 has 3.12
SUPPORTED = f"3D Slicer {MIN_SLICER[0]}.{MIN_SLICER[1]} or newer"

_UPPER = ("<", "<=")  # bounds a newer installed version breaks: a conflict, never a downgrade


class UnsupportedSlicer(RuntimeError):
    """This Slicer (its Python) is older than Resecta supports."""


class DependencyConflict(RuntimeError):
    """An installed package is newer than Resecta's range; Resecta does not downgrade it."""


class MissingClient(RuntimeError):
    """Neither the shipped client nor a checkout's is there (an incomplete installation)."""


def _version_key(text: str):
    """Comparable version: `packaging`'s when it is there, else the numeric release parts."""
    try:
        from packaging.version import Version
    except ImportError:
        parts = [int(p) for p in re.match(r"\d+(?:\.\d+)*", text).group().split(".")]
        while len(parts) > 1 and parts[-1] == 0:
            parts.pop()
        return tuple(parts)
    return Version(text)


_OPS = {
    ">=": lambda a, b: a >= b,
    ">": lambda a, b: a > b,
    "<": lambda a, b: a < b,
    "<=": lambda a, b: a <= b,
}


@dataclass(frozen=True)
class Requirement:
    """A distribution name with a version range (`>=`/`>` lower, `<`/`<=` upper bounds)."""

    name: str
    bounds: tuple[tuple[str, str], ...]

    @classmethod
    def parse(cls, line: str) -> Requirement:
        m = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)\s*(.*)", line.strip())
        spec = re.sub(r"\s", "", m.group(2)) if m else ""
        bounds = tuple(re.findall(r"(>=|<=|==|!=|~=|<|>)([0-9][0-9A-Za-z.+!-]*)", spec))
        if not m or ",".join(op + v for op, v in bounds) != spec:
            raise ValueError(f"cannot read requirement {line!r}")
        if not bounds or any(op not in _OPS for op, _ in bounds):
            raise ValueError(f"{line!r}: give a range with >=, >, <, <= (no pins: other "
                             "extensions share these packages)")
        return cls(m.group(1), bounds)

    def __str__(self) -> str:
        return self.name + ",".join(op + v for op, v in self.bounds)

    def violated(self, installed: str) -> list[str]:
        """The operators of the bounds `installed` does not meet."""
        have = _version_key(installed)
        return [op for op, v in self.bounds if not _OPS[op](have, _version_key(v))]


def requirements(path: Path = REQUIREMENTS) -> list[Requirement]:
    """The packages of `Resources/requirements.txt` (comments and blank lines skipped)."""
    lines = (line.split("#", 1)[0].strip() for line in path.read_text(encoding="utf-8").splitlines())
    return [Requirement.parse(line) for line in lines if line]


def installed_version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


@dataclass(frozen=True)
class Install:
    """One requirement pip must install (`installed` is None) or upgrade."""

    requirement: Requirement
    installed: str | None

    def __str__(self) -> str:
        if self.installed is None:
            return f"{self.requirement} (not installed)"
        return f"{self.requirement} (installed {self.installed}: upgraded)"


def plan(reqs: list[Requirement] | None = None) -> list[Install]:
    """What must be installed or upgraded; `DependencyConflict` when a package is too new."""
    todo, conflicts = [], []
    for req in requirements() if reqs is None else reqs:
        have = installed_version(req.name)
        broken = [] if have is None else req.violated(have)
        if any(op in _UPPER for op in broken):
            conflicts.append(f"{req.name} {have} is installed; Resecta needs {req}")
        elif have is None or broken:
            todo.append(Install(req, have))
    if conflicts:
        raise DependencyConflict(
            "Installed Python packages are newer than Resecta supports:\n  "
            + "\n  ".join(conflicts)
            + "\nResecta does not downgrade them (other extensions may need these versions). "
            "Use a Slicer installation without them, or a Resecta release made for them.")
    return todo


def check_slicer_version(slicer_version: str, python_version: tuple[int, ...] = sys.version_info[:2]) -> None:
    """Raises `UnsupportedSlicer` for a Slicer older than `MIN_SLICER` or a Python older than
    `MIN_PYTHON` (pass `slicer.app.applicationVersion`, e.g. "5.10.0" or "5.11.0-2026-01-15")."""
    m = re.match(r"(\d+)\.(\d+)", slicer_version)
    if not m:
        raise ValueError(f"not a Slicer version: {slicer_version!r}")
    slicer, python = (int(m[1]), int(m[2])), tuple(python_version[:2])
    if slicer < MIN_SLICER or python < MIN_PYTHON:
        raise UnsupportedSlicer(
            f"Resecta needs {SUPPORTED} (Python {MIN_PYTHON[0]}.{MIN_PYTHON[1]} or newer); this is "
            f"3D Slicer {slicer_version} with Python {python[0]}.{python[1]}. The packages its "
            "client needs (grpcio >= 1.85.1, protobuf >= 7.35.1) are not built for older Pythons: "
            "please install a newer 3D Slicer.")


def client_path() -> Path:
    """The folder holding the `resecta_client` package: the shipped one, else a checkout's."""
    for folder in (BUNDLED_CLIENT, CHECKOUT_CLIENT):
        if (folder / "resecta_client" / "__init__.py").is_file():
            return folder
    raise MissingClient(f"the resecta client is missing: neither {BUNDLED_CLIENT} (the extension's "
                        f"build puts it there) nor {CHECKOUT_CLIENT} (a checkout) holds resecta_client")


def use_client() -> Path:
    """Puts `client_path()` first on `sys.path` (once) and returns it."""
    folder = client_path()
    if str(folder) not in sys.path:
        sys.path.insert(0, str(folder))
        importlib.invalidate_caches()
    return folder


def _slicer_pip_install(args: list[str]) -> None:
    import slicer  # only inside Slicer: pip_install is a Slicer helper

    slicer.util.pip_install(args)  # a list: each item is one argument, never split or re-quoted


def ensure_installed(confirm: Callable[[list[str]], bool],
                     install: Callable[[list[str]], None] = _slicer_pip_install) -> bool:
    """True when the client and every package fit (installing after `confirm(lines)` said yes,
    one line per package); False when the user declined. Raises `DependencyConflict` or
    `MissingClient` (nothing installed), or when pip did not leave the ranges met."""
    use_client()
    todo = plan()
    if not todo:
        return True
    if not confirm([str(i) for i in todo]):
        return False
    install([str(i.requirement) for i in todo])
    importlib.invalidate_caches()
    left = plan()
    if left:
        raise RuntimeError("pip finished but these are still not met: " + ", ".join(map(str, left)))
    return True
