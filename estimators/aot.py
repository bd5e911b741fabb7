"""Build ``estimators._kernels``: the kernels declared with :func:`estimators.jit.aot` (the
robot pipeline's, the wearable tracker's with the helpers they call) compiled ahead of time
by numba's ``pycc`` from their Python source, into an extension module that needs numpy only
(see :mod:`estimators.jit` for why). About 1.5 min of CPU on a first build (the helpers
compiled by numba's JIT, then the module), less with numba's cache warm.

    python -m estimators.aot [--check] [--out DIR]

``--check`` only reports (exit status 1 if a kernel is missing from the built module).
Build-time only (at run time only :func:`mode`, which reports what a process runs):
``./run``'s set-up and the Docker image run it; without the module every
kernel is numba's JIT, the same code. numba marks ``pycc`` as pending deprecation (0.57) with
no replacement yet: the day it goes, the fallback keeps everything working, slower to start.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from pathlib import Path
from types import ModuleType
from typing import Any, Literal

from estimators import jit

Mode = Literal["ahead-of-time", "jit", "interpreted"]

# the modules holding the kernels declared with ``aot``
KERNEL_MODULES = (
    "estimators.filters",
    "estimators.heading",
    "estimators.imu_stage",
    "estimators.peaks",
    "estimators.rows",
    "estimators.wearable.kernel",
    "estimators.wearable.steps",
)
PACKAGE_DIR = Path(__file__).resolve().parent


def kernels() -> dict[str, jit.Kernel]:
    """Every ahead-of-time kernel, by export name."""
    for m in KERNEL_MODULES:
        importlib.import_module(m)
    return dict(jit.KERNELS)


def missing(module: ModuleType | None) -> list[str]:
    """Export names of the current kernels that ``module`` does not hold."""
    return [k for k in kernels() if module is None or not hasattr(module, k)]


def built() -> ModuleType | None:
    """The built module in the package, None if there is none (or none for this Python)."""
    try:
        return importlib.import_module(jit.MODULE)
    except ImportError:
        return None


def mode() -> Mode:
    """How this process runs the kernels: ``interpreted`` (``NUMBA_DISABLE_JIT=1``), ``jit``
    (numba's JIT: the module not built here, built from older sources, or ``REHAB_AOT=0``)
    or ``ahead-of-time`` (every kernel from the built module). Imports the kernels' modules."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") != "0":
        return "interpreted"
    if os.environ.get("REHAB_AOT") == "0":
        return "jit"
    return "jit" if missing(built()) else "ahead-of-time"


def build(out_dir: Path) -> Path:
    """Compile every kernel into ``out_dir``/_kernels<suffix>; returns the file."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pycc's pending deprecation
        pycc: Any = importlib.import_module("numba.pycc")  # untyped

    todo = kernels()
    jit.load()  # the helpers the kernels call as numba's dispatchers
    name = jit.MODULE.rsplit(".", 1)[-1]
    cc = pycc.CC(name, source_module=__name__)
    cc.output_dir = str(out_dir)
    for k in todo.values():
        cc.export(k.export, k.signature)(k.fn)
    cc.compile()  # for any x86-64 CPU (pycc's default target), so an image runs anywhere
    return out_dir / str(cc.output_file)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--check", action="store_true", help="only report what is missing")
    ap.add_argument("--out", type=Path, default=PACKAGE_DIR, help="directory of the module")
    args = ap.parse_args(argv)
    module = built()
    todo = missing(module)
    if args.check:
        for k in todo:
            print(f"not built (or stale): {k}")
        return 1 if todo else 0
    if not todo and args.out.resolve() == PACKAGE_DIR and module is not None:
        # touched, so that ./run's check (the module newer than the estimators) passes
        os.utime(str(module.__file__))
        print(f"{jit.MODULE}: up to date ({len(kernels())} kernels)")
        return 0
    path = build(args.out)
    print(f"built {path} ({len(kernels())} kernels)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
