#!/usr/bin/env python3
"""Lays out the Resecta extension's files as the Extension Manager installs them, without CMake:
`<out>/lib/Slicer-<X.Y>/qt-scripted-modules/` holding `Resecta.py`, `ResectaLib/`, `Resources/`
and the shipped client (`Resources/Python/resecta_client`). The file lists are read from
`slicer-module/Resecta/CMakeLists.txt` (MODULE_PYTHON_SCRIPTS, MODULE_PYTHON_RESOURCES,
RESECTA_CLIENT_FILES into RESECTA_CLIENT_SUBDIR), so the CMake build and this script install the
same files. The tests import the module from such a layout; a developer can point Slicer's
*Additional module paths* at the printed folder to try the installed extension.

    python slicer-module/scripts/install_layout.py OUT [--slicer 5.10]
"""

from __future__ import annotations

import argparse
import re
import shutil
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MODULE = REPO / "slicer-module" / "Resecta"
MODULE_CMAKE = MODULE / "CMakeLists.txt"


def cmake_sets(path: Path = MODULE_CMAKE, **known: str) -> dict[str, list[str]]:
    """The unquoted `set(NAME items...)` of a CMakeLists, in order, with `${VAR}` expanded from
    earlier sets and from `known` (comments dropped)."""
    values = {k: [v] for k, v in known.items()}
    text = re.sub(r"#[^\n]*", "", path.read_text(encoding="utf-8"))
    for name, body in re.findall(r"\bset\(\s*(\w+)\s+([^)\"]*)\)", text):
        values[name] = [re.sub(r"\$\{(\w+)\}", lambda m: " ".join(values[m[1]]), item)
                        for item in body.split()]
    return values


def module_files() -> list[tuple[Path, str]]:
    """(source file, path under qt-scripted-modules) of every file the CMake build installs."""
    sets = cmake_sets(Resecta_SOURCE_DIR=str(REPO), CMAKE_CURRENT_SOURCE_DIR=str(MODULE))
    files = [(MODULE / rel, rel) for key in ("MODULE_PYTHON_SCRIPTS", "MODULE_PYTHON_RESOURCES")
             for rel in sets[key]]
    client_dir, (subdir,) = Path(*sets["RESECTA_CLIENT_SOURCE_DIR"]), sets["RESECTA_CLIENT_SUBDIR"]
    files += [(client_dir / rel, f"{subdir}/{rel}") for rel in sets["RESECTA_CLIENT_FILES"]]
    return files


def install(out: Path, slicer: str = "5.10") -> Path:
    """Copies `module_files()` into `out/lib/Slicer-<slicer>/qt-scripted-modules` (returned)."""
    dest = Path(out) / "lib" / f"Slicer-{slicer}" / "qt-scripted-modules"
    for src, rel in module_files():
        if not src.is_file():
            raise FileNotFoundError(f"{MODULE_CMAKE} lists {src}, which is missing")
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dest / rel)
    return dest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--slicer", default="5.10", help="Slicer major.minor of the lib folder")
    args = parser.parse_args()
    print(install(args.out, args.slicer))


if __name__ == "__main__":
    main()
