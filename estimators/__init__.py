"""The method's estimators: pure numpy/scipy functions and small classes, no I/O.

Optional compiled build. ``scripts/build_native.py`` (run by ``./run`` at set-up when a C
compiler is at hand) compiles the live path's modules, :data:`NATIVE_MODULES`, from these
same sources with mypyc into ``_native/``. This bootstrap, the package's only file access,
puts that build first on the package's path only if it was made from the sources as they
are now (a digest of them is stored beside it), so an edited source is never shadowed by a
stale build. ``REHAB_PURE=1`` keeps the interpreted modules. Both give identical numbers
(``tests/estimators/test_native.py``).
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import os
import sys
from pathlib import Path

# the modules a live poll spends its time in. Not boundary.py: compiled code would unbox
# its float subclass. Not output.py: a compiled subclass of an ABC (RowTable, a Mapping)
# shares the ABC's isinstance cache, so any dict would pass for one.
NATIVE_MODULES = (
    "buffers",
    "compensation",
    "cycles",
    "grid_stage",
    "heading",
    "imu_stage",
    "pipeline",
    "robot_stage",
    "rows",
    "verdicts",
)
_HERE = Path(__file__).resolve().parent
NATIVE_DIR = _HERE / "_native"
NATIVE_STAMP = NATIVE_DIR / "SOURCES"  # the digest the build was made from, written last


def sources_digest() -> str:
    """sha256 of the compiled modules' sources and of this interpreter's version."""
    h = hashlib.sha256(sys.version.encode())
    for name in NATIVE_MODULES:
        h.update((_HERE / f"{name}.py").read_bytes())
    return h.hexdigest()


def built_from() -> str | None:
    """The digest the compiled build was made from, or None if there is none."""
    try:
        return NATIVE_STAMP.read_text().strip()
    except OSError:
        return None


def _load_native() -> bool:
    if os.environ.get("REHAB_PURE", "") not in ("", "0"):
        return False
    if built_from() != sources_digest():
        return False
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    groups = sorted(NATIVE_DIR.glob(f"*__mypyc{suffix}"))
    if len(groups) != 1:
        return False
    # the modules' shared library, which their shims import by its top-level name
    name = groups[0].name[: -len(suffix)]
    spec = importlib.util.spec_from_file_location(name, groups[0])
    if spec is None or spec.loader is None:
        return False
    lib = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(lib)
    sys.modules[name] = lib
    __path__.insert(0, str(NATIVE_DIR))
    return True


NATIVE: bool = _load_native()
"""Whether the compiled build of :data:`NATIVE_MODULES` is in use."""
