"""Streaming cost in CPU instructions per poll: the same count on any day, for comparing commits.

The live loop of ``speed.py`` (a poll after every robot message) runs under valgrind's
callgrind twice: once feeding and polling, once only decoding the same messages. The
difference over the number of polls is the pipeline's cost per poll (one robot sample, one
IMU message of 4 samples, the fusion grid and heading updates amortised). A shared virtual
machine's speed drifts by up to 2x within minutes, so microseconds (``speed.py``) cannot show
a 5 % change; this count can. At about 4 instructions per ns (this machine, a quiet minute),
80 µs per poll (20 µs per IMU sample) is about 320 k instructions.

Needs valgrind (a system package, not a project dependency); about 2 minutes with the
defaults.

    python benchmarks/instructions.py [--seed 1] [--messages 12000]
"""

from __future__ import annotations

import argparse
import gc
import pickle
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from protocol import wire
from simulator import SimConfig, simulate


def child(path: Path, mode: str) -> None:
    """Decode the messages; with ``mode == "poll"`` also stream them through a pipeline."""
    raw = pickle.loads(path.read_bytes())
    msgs = [wire.decode(k, p) for k, p in raw]
    gc.collect()
    gc.freeze()  # as speed.py: the input messages are not the pipeline's to walk
    if mode == "poll":
        p = Pipeline(PipelineParams())
        for m in msgs:
            p.feed(m)
            if isinstance(m, wire.RobotMessage):
                p.poll()


def count(path: Path, mode: str, tmp: Path) -> int:
    """Instructions of ``child(path, mode)`` in a fresh interpreter under callgrind."""
    proc = subprocess.run(
        [
            "valgrind",
            "--tool=callgrind",
            f"--callgrind-out-file={tmp / ('callgrind.' + mode)}",
            sys.executable,
            __file__,
            "--child",
            mode,
            str(path),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    m = re.search(r"Collected : (\d+)", proc.stderr)
    if m is None:
        raise RuntimeError(f"no instruction count from valgrind:\n{proc.stderr[-2000:]}")
    return int(m.group(1))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--messages", type=int, default=12000, help="the first N (0: all)")
    ap.add_argument("--child", nargs=2, metavar=("MODE", "FILE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(Path(args.child[1]), args.child[0])
        return 0
    if shutil.which("valgrind") is None:
        print("valgrind not found (Debian: apt install valgrind)", file=sys.stderr)
        return 2
    messages = simulate(SimConfig(seed=args.seed, duration_s=args.duration)).messages
    if args.messages:
        messages = messages[: args.messages]
    polls = sum(isinstance(wire.decode(k, p), wire.RobotMessage) for k, p in messages)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        path = tmp / "messages.pickle"
        path.write_bytes(pickle.dumps(list(messages)))
        polled, decoded = count(path, "poll", tmp), count(path, "decode", tmp)
    per_poll = (polled - decoded) / polls
    print(
        f"streaming (poll after every robot message): {per_poll / 1e3:.1f} k instructions per "
        f"poll ({polls} polls, {len(messages)} messages, seed {args.seed})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
