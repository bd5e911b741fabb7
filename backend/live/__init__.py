"""The live service: Zenoh ingest, one pipeline per device, sessions, outputs and feeds.

Data path (one asyncio loop; Zenoh's threads only enqueue)::

    zenoh callback ─► ZenohIO buffer ─► Ingest.route ─► DeviceWorker queue (one per device)
        ─► LiveRun: record the raw line, decode, feed, poll
        ─► estimate/feedback on Zenoh, WebSocket hub, session files, DbWriter

:class:`backend.live.manager.LiveManager` wires it together and implements
:class:`backend.deps.LiveHooks`.
"""
