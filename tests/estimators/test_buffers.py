"""The row FIFOs give back exactly what went in, in order, however it is put and taken."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.buffers import RowQueue

# a schedule: ("push", 1) one row, ("append", k) a block of k rows, ("block", k) take k
ops = st.lists(
    st.tuples(st.sampled_from(["push", "append", "block"]), st.integers(0, 7)),
    max_size=40,
)


@settings(max_examples=200, deadline=None)
@given(ops)
def test_row_queue_is_a_fifo(schedule: list[tuple[str, int]]) -> None:
    q = RowQueue(3)
    made: list[list[float]] = []
    taken: list[list[float]] = []
    for op, k in schedule:
        if op == "push":
            row = [float(len(made)), 0.5, -1.0]
            made.append(row)
            q.push(tuple(row))
        elif op == "append":
            block = np.array([[float(len(made) + i), 0.5, -1.0] for i in range(k)]).reshape(k, 3)
            made.extend(block.tolist())
            q.append(block)
        else:
            k = min(k, len(made) - len(taken))
            b = q.take_block(k)
            assert b.shape == (k, 3)
            got = b.tolist()
            taken.extend(got)
    assert taken == made[: len(taken)]
    rest = len(made) - len(taken)
    assert q.take_block(rest).tolist() == made[len(taken) :]
