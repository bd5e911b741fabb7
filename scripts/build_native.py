"""Compile the live path's estimator modules with mypyc, for ``estimators/_native/``.

The compiled modules are the same sources, so they give the same numbers (tested); they run
a live poll in about three quarters of the time (``docs/benchmarks.md``). Without a C
compiler and Python's headers nothing is built and the estimators run interpreted, as
with ``REHAB_PURE=1``. ``./run`` calls this at set-up; it rebuilds only when the sources
changed (``estimators.sources_digest``).

    python scripts/build_native.py [--force] [--strict] [--clean]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import estimators  # noqa: E402  (after the path: the checkout's, not an installed copy)

_MYPY_INI = "[mypy]\npython_version = 3.11\nignore_missing_imports = True\n"


def _compiler() -> str | None:
    """Why a build is impossible here, or None."""
    cc = (sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(cc) is None:
        return f"no C compiler ({cc})"
    if not (Path(sysconfig.get_paths()["include"]) / "Python.h").is_file():
        return "no Python headers (Python.h)"
    return None


def build() -> None:
    """Compile in a scratch copy of the package; replace ``_native/`` only when done."""
    digest = estimators.sources_digest()
    src = ROOT / "estimators"
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        (tmp / "estimators").mkdir()
        for f in src.glob("*.py"):  # all of them: the compiled ones import the rest
            shutil.copy2(f, tmp / "estimators" / f.name)
        (tmp / "mypy.ini").write_text(_MYPY_INI)
        files = [f"estimators/{m}.py" for m in estimators.NATIVE_MODULES]
        proc = subprocess.run(
            [sys.executable, "-m", "mypyc", *files],
            cwd=tmp,
            capture_output=True,
            text=True,
            env={**os.environ, "MYPYC_OPT_LEVEL": "3"},
        )
        if proc.returncode != 0:
            raise RuntimeError(f"mypyc failed:\n{(proc.stdout + proc.stderr)[-3000:]}")
        suffix = sysconfig.get_config_var("EXT_SUFFIX")
        built = sorted(tmp.glob(f"*__mypyc{suffix}")) + [
            tmp / "estimators" / f"{m}{suffix}" for m in estimators.NATIVE_MODULES
        ]
        missing = [p.name for p in built if not p.is_file()]
        if missing or len(built) != len(estimators.NATIVE_MODULES) + 1:
            raise RuntimeError(f"mypyc left no {missing or 'shared library'}")
        out = estimators.NATIVE_DIR
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()
        for p in built:
            shutil.copy2(p, out / p.name)
        estimators.NATIVE_STAMP.write_text(digest + "\n")  # last: valid once complete


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--force", action="store_true", help="rebuild even if up to date")
    ap.add_argument("--strict", action="store_true", help="fail if the compiler fails")
    ap.add_argument("--clean", action="store_true", help="remove the build and stop")
    args = ap.parse_args(argv)
    if args.clean:
        shutil.rmtree(estimators.NATIVE_DIR, ignore_errors=True)
        return 0
    if not args.force and estimators.built_from() == estimators.sources_digest():
        return 0
    why = _compiler()
    if why is not None:
        print(f"{why}: the estimators run interpreted (the same numbers, slower)")
        return 0
    print("compiling the live path's estimators with mypyc (about a minute)", flush=True)
    t0 = time.monotonic()
    try:
        build()
    except (RuntimeError, OSError) as e:
        print(f"{e}\nthe estimators run interpreted", file=sys.stderr)
        return 1 if args.strict else 0
    print(f"compiled in {time.monotonic() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
