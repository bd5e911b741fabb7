"""`rehab analyze` and `rehab evaluate` exactly as contract §6."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from backend.analysis import CSV_HEADER, read_estimates
from backend.cli import main
from protocol import recording
from tests.conftest import Session


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory, short_session: Session) -> Path:
    d = tmp_path_factory.mktemp("rec")
    recording.write(d / "recording.jsonl.gz", short_session.raw)
    short_session.sim.truth.save(d / "truth.npz")
    return d


def test_analyze_writes_the_contract_files(rec: Path, short_session: Session, capsys) -> None:
    assert main(["analyze", str(rec / "recording.jsonl.gz"), "--out", str(rec / "out")]) == 0
    lines = (rec / "out" / "estimates.csv").read_text().splitlines()
    assert lines[0] == CSV_HEADER
    n_robot = sum(len(p["t"]) for k, p in short_session.raw if k.endswith("/robot"))
    assert len(lines) - 1 == n_robot
    est = read_estimates(rec / "out" / "estimates.csv")
    assert set(np.unique(est["heading_converged"])) <= {0.0, 1.0}
    assert set(est["state"]) <= {"", "ok", "outside", "warning"}
    rep = json.loads((rec / "out" / "report.json").read_text())
    assert rep["cycles"], "cycles are judged"
    for c in rep["cycles"]:
        assert {"start", "end", "outside_fraction", "compensatory"} <= set(c)
        assert isinstance(c["compensatory"], bool) and c["end"] > c["start"]
    assert "estimates" in capsys.readouterr().out


def test_analyze_many_recordings_in_parallel(rec: Path, tmp_path: Path, capsys) -> None:
    """Several recordings with --jobs: DIR/<name>/ each, the same files as one by one; a
    missing recording is refused before any work."""
    src = rec / "recording.jsonl.gz"
    a, b = tmp_path / "s1.jsonl.gz", tmp_path / "s2.jsonl.gz"
    a.write_bytes(src.read_bytes())
    b.write_bytes(src.read_bytes())
    main(["analyze", str(src), "--out", str(tmp_path / "one")])
    assert main(["analyze", str(a), str(b), "--out", str(tmp_path / "many"), "--jobs", "2"]) == 0
    for name in ("s1", "s2"):
        for f in ("estimates.csv", "details.csv"):
            assert (tmp_path / "many" / name / f).read_bytes() == (
                tmp_path / "one" / f
            ).read_bytes()
    assert capsys.readouterr().out.count("estimates") == 3
    assert main(["analyze", str(a), str(tmp_path / "no.jsonl"), "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


def test_analyze_imports_neither_the_service_nor_the_simulator(rec: Path, tmp_path: Path) -> None:
    """Start-up: `rehab analyze` loads only what it runs (not FastAPI, SQLAlchemy, Zenoh, the
    simulators' SciPy), while `rehab serve` still finds its command."""
    code = (
        "import sys; from backend.cli import main; "
        f"main(['analyze', {str(rec / 'recording.jsonl.gz')!r}, '--out', {str(tmp_path)!r}]); "
        "print(' '.join(sorted(sys.modules)))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    loaded = set(out.splitlines()[-1].split())
    assert "backend.analysis" in loaded
    for heavy in ("fastapi", "sqlalchemy", "zenoh", "uvicorn", "simulator.wearable", "backend.app"):
        assert heavy not in loaded, heavy
    serve = subprocess.run(
        [sys.executable, "-m", "backend.cli", "serve", "--help"], capture_output=True, text=True
    )
    assert serve.returncode == 0 and "--workers" in serve.stdout


def _both_ways(code: str, tmp_path: Path) -> list[tuple[str, list[str]]]:
    """Runs ``code`` (an analysis into ``sys.argv[1]``, then a line of fields) with the built
    kernels (``REHAB_AOT=1``, into ``tmp_path/aot``) and with numba's JIT (``0``, ``jit``):
    ``(REHAB_AOT, fields)`` each; skips the test when the module is not built (its first
    field ``False`` with ``REHAB_AOT=1``)."""
    runs = []
    for out, aot_env in (("aot", "1"), ("jit", "0")):
        run = subprocess.run(
            [sys.executable, "-c", code, str(tmp_path / out)],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, "REHAB_AOT": aot_env},
        )
        fields = run.stdout.splitlines()[-1].split()
        if aot_env == "1" and fields[0] == "False":
            pytest.skip(
                "kernels not built, or built from an older source: python -m estimators.aot"
            )
        runs.append((aot_env, fields))
    return runs


def test_analyze_with_kernels_built_ahead_of_time(rec: Path, tmp_path: Path) -> None:
    """With ``estimators._kernels`` built (``./run``'s set-up): `rehab analyze` imports no
    numba, and writes the same bytes as with numba's JIT of the same kernels (REHAB_AOT=0)."""
    code = (
        "import sys; from backend.cli import main; "
        f"main(['analyze', {str(rec / 'recording.jsonl.gz')!r}, '--out', sys.argv[1]]); "
        "from estimators import aot, jit; "
        "print(all(jit.uses_aot(getattr(sys.modules[k.fn.__module__], k.fn.__name__)) "
        "for k in aot.kernels().values()), 'numba' in sys.modules)"
    )
    for aot_env, (used, numba) in _both_ways(code, tmp_path):
        assert (used, numba) == (("True", "False") if aot_env == "1" else ("False", "True"))
    for f in ("estimates.csv", "details.csv", "report.json"):
        assert (tmp_path / "aot" / f).read_bytes() == (tmp_path / "jit" / f).read_bytes()


@pytest.mark.parametrize("camera", [False, True])
def test_wearable_analyze_with_kernels_built_ahead_of_time(tmp_path: Path, camera: bool) -> None:
    """The same for a wearable session (the tracker's kernels with the helpers they call):
    no numba, the same joints.csv and report.json as numba's JIT (REHAB_AOT=0)."""
    sim = ["simulate", "--mode", "wearable", "--duration", "20", "--out", str(tmp_path / "s")]
    assert main(sim if camera else [*sim, "--no-camera"]) == 0
    s = tmp_path / "s"
    code = (
        "import sys; from backend.cli import main; "
        f"main(['analyze', {str(s / 'recording.jsonl.gz')!r}, '--params', "
        f"{str(s / 'params.json')!r}, '--out', sys.argv[1]]); "
        "from estimators import jit; from estimators.wearable import kernel, steps; "
        "print(all(jit.uses_aot(k) for k in (steps.feed, kernel.pose)), "
        "'numba' in sys.modules, 'scipy.linalg' in sys.modules)"
    )
    for aot_env, (used, numba, linalg) in _both_ways(code, tmp_path):
        # the built module's BLAS/LAPACK from SciPy's two Cython modules alone (jit._scipy_blas)
        assert (used, numba, linalg) == (
            ("True", "False", "False") if aot_env == "1" else ("False", "True", "True")
        )
    for f in ("joints.csv", "report.json"):
        assert (tmp_path / "aot" / f).read_bytes() == (tmp_path / "jit" / f).read_bytes()


def test_analyze_is_deterministic(rec: Path) -> None:
    main(["analyze", str(rec / "recording.jsonl.gz"), "--out", str(rec / "a")])
    main(["analyze", str(rec / "recording.jsonl.gz"), "--out", str(rec / "b")])
    for f in ("estimates.csv", "details.csv", "report.json"):
        assert (rec / "a" / f).read_bytes() == (rec / "b" / f).read_bytes()


def test_params_file_and_its_errors(rec: Path, tmp_path: Path) -> None:
    good = tmp_path / "p.json"
    good.write_text(json.dumps({"tolerance_m": 0.05, "displacement_norm": "3d"}))
    assert (
        main(
            [
                "analyze",
                str(rec / "recording.jsonl.gz"),
                "--params",
                str(good),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 0
    )
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert rep["params"]["tolerance_m"] == 0.05
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"tolerance": 0.05}))
    with pytest.raises(SystemExit, match="unknown parameter"):
        main(
            [
                "analyze",
                str(rec / "recording.jsonl.gz"),
                "--params",
                str(bad),
                "--out",
                str(tmp_path / "x"),
            ]
        )


def test_bad_lines_are_counted_not_fatal(rec: Path, tmp_path: Path, short_session: Session) -> None:
    raw = list(short_session.raw[:3000])
    raw.insert(100, ("rehab/sim01/robot", {"t": [1.0], "wrist": [[0, 0]], "proximal": [[0, 0, 0]]}))
    raw.insert(200, ("rehab/sim01/bogus", {}))
    raw.insert(
        300, ("rehab/sim01/imu/upperarm", {"t": [0.0], "gyr": [[0, 0, 0]], "acc": [[0, 0, 9.8]]})
    )
    path = tmp_path / "r.jsonl"
    recording.write(path, raw)
    with path.open("a") as fh:
        fh.write('not json\n{"key": 1}\n')
    assert main(["analyze", str(path), "--out", str(tmp_path / "o")]) == 0
    q = json.loads((tmp_path / "o" / "report.json").read_text())["data_quality"]["rejected"]
    assert q == {"bad_shape": 1, "malformed_line": 2, "time_backwards": 1, "unknown_key": 1}


def test_empty_recording(tmp_path: Path) -> None:
    (tmp_path / "empty.jsonl").write_text("")
    assert main(["analyze", str(tmp_path / "empty.jsonl"), "--out", str(tmp_path / "o")]) == 0
    assert (tmp_path / "o" / "estimates.csv").read_text() == CSV_HEADER + "\n"
    assert json.loads((tmp_path / "o" / "report.json").read_text())["cycles"] == []


def test_missing_recording_is_a_clear_error(tmp_path: Path, capsys) -> None:
    assert main(["analyze", str(tmp_path / "nope.jsonl"), "--out", str(tmp_path / "o")]) == 2
    assert "no such recording" in capsys.readouterr().err


def test_evaluate_prints_the_papers_tables(rec: Path, capsys) -> None:
    main(["analyze", str(rec / "recording.jsonl.gz"), "--out", str(rec / "ev")])
    capsys.readouterr()
    assert (
        main(
            [
                "evaluate",
                str(rec / "ev"),
                "--truth",
                str(rec / "truth.npz"),
                "--json",
                str(rec / "ev.json"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "| proper |" in out and "| compensatory |" in out and "heading converged" in out
    res = json.loads((rec / "ev.json").read_text())
    assert res["cycles"]["share_correct"] == 1.0
    assert res["accuracy"]["compensatory"]["conv_shoulder_m"]["median"] > 0.05  # baseline fails
