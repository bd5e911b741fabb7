"""The contract's wire: Zenoh keys, payload schema, recording format and connection config.

Shared by the service (``backend``), the simulator and independent tools, so that none of
them imports another's internals (``../shared/contract.md`` is the specification)."""
