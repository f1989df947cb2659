"""Zero tracking: every stored health model gets its loss-drift tracking state.

A conveyor's ``monitor_states.state`` gains ``zero_tracking``: the loss
drift and its rate after the last known run, the scale learned from the
sequence of known runs and the recent recordings' signature differences
(:class:`chaintwin.weigh.zero_tracking.ZeroTracker`). It is kept in the
health model's JSON, so that it is written in the same transaction and
under the same version as the model. The upgrade gives every stored model
an empty tracking state (nothing known yet: the ±10 % default until the
first known run); the downgrade takes it out again.

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-28
"""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0011"
down_revision = "0010"
branch_labels = None
depends_on = None

EMPTY: dict[str, Any] = {
    "version": 2,
    "at": None,
    "state": [0.0, 0.0],
    "covariance": [[0.0, 0.0], [0.0, 0.0]],
    "innovations": [],
    "warm": [],
    "history": [],
    "reference_var": 0.0,
}
"""An empty tracking state, as ``ZeroTracker().to_dict()`` writes it."""


def _states() -> sa.TableClause:
    return sa.table(
        "monitor_states",
        sa.column("conveyor_id", sa.String(200)),
        sa.column("state", sa.JSON()),
    )


def upgrade() -> None:
    states = _states()
    bind = op.get_bind()
    for conveyor, state in bind.execute(sa.select(states.c.conveyor_id, states.c.state)).all():
        if not isinstance(state, dict) or "zero_tracking" in state:
            continue
        bind.execute(
            states.update()
            .where(states.c.conveyor_id == conveyor)
            .values(state=dict(state, zero_tracking=dict(EMPTY)))
        )


def downgrade() -> None:
    states = _states()
    bind = op.get_bind()
    for conveyor, state in bind.execute(sa.select(states.c.conveyor_id, states.c.state)).all():
        if not isinstance(state, dict) or "zero_tracking" not in state:
            continue
        kept = {k: v for k, v in state.items() if k != "zero_tracking"}
        bind.execute(states.update().where(states.c.conveyor_id == conveyor).values(state=kept))
