"""Live cost of one wearable device (issue 19: 20 wearable devices beside the robot devices).

A simulated two-IMU + camera session (100 Hz, 10-sample messages, camera 30 Hz) is fed
message by message through the live service's run (:class:`WearableLiveRun`: the recorded
form, decoding, the tracker, a poll after each message, the joints payload and the dashboard
block, as the worker builds them), without Zenoh or files. Prints the CPU per device-second
and how many such devices one core carries in real time.

    python benchmarks/wearable_live.py [--seconds 60] [--filter ekf|ukf]
"""

from __future__ import annotations

import argparse
import time

from backend import analysis_wearable as aw
from backend.live import feed
from backend.live.devices import DeviceStats
from backend.live.ingest import RawMessage
from backend.live.wearable_run import WearableLiveRun
from estimators.wearable.params import WearableParams
from protocol import wire
from simulator import wearable as sw


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated session length")
    ap.add_argument("--filter", choices=("ekf", "ukf"), default="ekf")
    args = ap.parse_args()
    sim = sw.simulate(sw.WearableSimConfig(move="reaching", duration_s=args.seconds, seed=1))
    params = WearableParams.from_json({**sim.params, "filter": args.filter})
    raws = []
    for key, payload in sim.messages:
        data = wire.dumps(payload)
        raws.append(RawMessage(key, data, len(data), 0.0, key.split("/")[2]))
    run = WearableLiveRun("wear01", "rehab", DeviceStats("wear01"), params=params)
    rows = 0
    start = time.process_time()
    for m in raws:
        run.ingest(m)
        out = run.poll()
        if out is not None and out.rows is not None:
            rows += out.n
            wire.joints_payload(out.rows, feed.JOINTS_EXTRA)
            feed.joints_block(out.rows)
    cpu = time.process_time() - start
    per_s = cpu / args.seconds
    # the same lines through rehab analyze's run alone: the rest is the live layer's cost
    offline = aw.WearableRun(params, "wear01")
    start = time.process_time()
    for m in raws:
        assert m.payload is not None
        offline.feed_line(m.key, m.payload)
    tracker_cpu = time.process_time() - start
    print(
        f"{args.filter.upper()}: {rows} rows of {args.seconds:g} s in {cpu:.2f} s CPU: "
        f"{1000 * per_s:.1f} ms per device-second, {1e6 * cpu / max(rows, 1):.0f} us per row, "
        f"{1 / per_s:.1f} devices per core in real time; of which the tracker "
        f"(rehab analyze's run) {1000 * tracker_cpu / args.seconds:.1f} ms"
    )


if __name__ == "__main__":
    main()
