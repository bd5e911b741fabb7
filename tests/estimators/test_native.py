"""The compiled build of the live path's modules (``scripts/build_native.py``): used only when
it matches the sources, switched off by ``REHAB_PURE=1``, and bit-identical to the
interpreted modules."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest

import estimators
from estimators.output import RowTable

ROOT = Path(__file__).resolve().parents[2]
built = pytest.mark.skipif(
    estimators.built_from() is None,
    reason="no compiled build (scripts/build_native.py; ./run test makes one)",
)

# A session streamed three ways (a poll per robot message, at random, one batch call):
# a digest of every output, and which modules ran.
_DIGEST = """
import hashlib, json, pickle, random, sys
import numpy as np
import estimators
from backend import wire
from estimators import pipeline as pl
from estimators.output import ROW_COLUMNS
from estimators.params import PipelineParams
from simulator import SimConfig, simulate

sim = simulate(SimConfig(seed=int(sys.argv[1]), duration_s=float(sys.argv[2])))
msgs = [wire.decode(k, p) for k, p in sim.messages]
out = {"native": estimators.NATIVE, "file": pl.__file__}
for params in (PipelineParams(), PipelineParams(method="paper")):
    for how in ("robot", "random", "batch"):
        p, outs, rng = pl.Pipeline(params), [], random.Random(5)
        if how == "batch":
            outs.append(p.run(msgs))
        else:
            for m in msgs:
                p.feed(m)
                if (how == "robot" and isinstance(m, wire.RobotMessage)) or (
                    how == "random" and rng.random() < 0.2
                ):
                    outs.append(p.poll())
            outs.append(p.finish())
        h = hashlib.sha256()
        for o in outs:
            if o.n:
                for c in ROW_COLUMNS:
                    h.update(np.ascontiguousarray(o.rows[c]).tobytes())
            h.update(pickle.dumps((o.feedback, [repr(x) for x in o.cycles + o.episodes])))
        st = p.status()
        h.update(repr(st).encode())
        out[params.method + "/" + how] = h.hexdigest()
        out[params.method + "/" + how + "/rows"] = sum(o.n for o in outs)
print(json.dumps(out))
"""


def _run(code: str, *args: str, pure: bool, path: Path = ROOT) -> Any:
    """The JSON that ``code`` prints last, run in a fresh interpreter on the package at
    ``path``."""
    env = {**os.environ, "PYTHONPATH": str(path), "REHAB_PURE": "1" if pure else ""}
    proc = subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=path,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


_WHICH = (
    "import json, estimators, estimators.rows as r; "
    "print(json.dumps([estimators.NATIVE, r.__file__]))"
)


@built
def test_compiled_and_interpreted_give_identical_outputs() -> None:
    native = _run(_DIGEST, "3", "120", pure=False)
    pure = _run(_DIGEST, "3", "120", pure=True)
    assert native.pop("native") is True and pure.pop("native") is False
    assert str(native.pop("file")).endswith(".so") and str(pure.pop("file")).endswith(".py")
    assert native["improved/robot/rows"] == 3001  # every robot sample, 0 to 120 s at 25 Hz
    assert native == pure


def test_pure_switch_keeps_the_interpreted_modules() -> None:
    native, path = _which(pure=True)
    assert native is False and path.endswith("rows.py")


def _which(pure: bool, root: Path = ROOT) -> tuple[bool, str]:
    native, path = _run(_WHICH, pure=pure, path=root)
    return bool(native), str(path)


@built
def test_a_build_of_other_sources_is_not_used(tmp_path: Path) -> None:
    shutil.copytree(ROOT / "estimators", tmp_path / "estimators")
    assert _which(pure=False, root=tmp_path) == (True, _native_rows(tmp_path))
    rows = tmp_path / "estimators" / "rows.py"
    rows.write_text(rows.read_text() + "\n# edited after the build\n")
    native, path = _which(pure=False, root=tmp_path)
    assert native is False and path == str(rows)


def _native_rows(root: Path) -> str:
    return str(next((root / "estimators" / "_native").glob("rows.*")))


def test_a_row_table_is_not_any_mapping() -> None:
    # a mypyc-compiled RowTable inherited Mapping's isinstance cache: after a dict had been
    # checked against Mapping, every dict passed for a RowTable (and the service crashed)
    assert isinstance({}, Mapping)
    assert not isinstance({}, RowTable)
