"""``rehab demo`` starts, prints how to log in, streams two robot devices and a wearable
one, and stops by itself."""

from __future__ import annotations

import json
import re
import sqlite3
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_demo_runs_and_stops(tmp_path: Path) -> None:
    data = tmp_path / "demo"
    done = subprocess.run(
        [sys.executable, "-m", "backend.cli", "demo", "--duration", "6", "--data-dir", str(data)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert re.search(r"open http://127\.0\.0\.1:\d+/", out)
    password = re.search(r"log in as 'admin', password '([^']+)'", out)
    assert password is not None
    assert password.group(1) in (data / "admin-credentials.txt").read_text()
    with sqlite3.connect(data / "rehab.db") as db:
        devices = {name: stats for name, stats in db.execute("SELECT name, stats FROM devices")}
        patients = {code for (code,) in db.execute("SELECT code FROM patients")}
    assert set(devices) == {"sim01", "sim02", "wear01"}
    assert all(stats for stats in devices.values())  # data arrived, counters stored
    assert patients == {"demo-proper", "demo-drift", "demo-wearable"}
    # the wearable device runs the wearable tracker (its preview follows its streams)
    wear = json.loads(devices["wear01"])
    assert "flagged_rows" in wear["quality"], wear
