"""One alarm per conveyor and probable cause: open alarms of one cause grouped, old ids kept.

The open alarms of a conveyor that share a probable cause become one: the
oldest keeps its id and lead fields; the others' features join its
``evidence``, their ids its ``merged`` list, and an acknowledgement of any
of them carries over (the earliest). This is done in the health model
(``monitor_states.state``) and in ``alarms``, where the grouped rows leave.
``alarm_aliases`` maps each grouped id to the alarm it joined, so that old
ids (in reports, notifications, scripts) still name an alarm.

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-28
"""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def _evidence(alarm: dict[str, Any]) -> list[dict[str, Any]]:
    """An alarm's evidence; alarms kept before evidence existed rest on their feature."""
    found = alarm.get("evidence")
    if found:
        return list(found)
    return [
        {
            "feature": alarm["feature"],
            "kind": alarm.get("kind", "statistical"),
            "value": None,
            "z": None,
            "since": alarm.get("since"),
        }
    ]


def _group(alarms: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], dict[str, str]]:
    """The alarms with the open ones of a cause grouped into the oldest; old id -> new id."""
    keeper: dict[str, dict[str, Any]] = {}
    moved: dict[str, str] = {}
    kept: list[dict[str, Any]] = []
    for alarm in alarms:
        if alarm.get("status") != "open":
            kept.append(alarm)
            continue
        into = keeper.get(alarm["cause"])
        if into is None:
            into = dict(alarm, evidence=_evidence(alarm))
            keeper[alarm["cause"]] = into
            kept.append(into)
            continue
        known = {(e["feature"], e.get("kind", "statistical")) for e in into["evidence"]}
        into["evidence"] += [
            e for e in _evidence(alarm) if (e["feature"], e.get("kind", "statistical")) not in known
        ]
        into["merged"] = [*into.get("merged", []), alarm["id"], *alarm.get("merged", [])]
        comments = into.get("comments", []) + alarm.get("comments", [])
        if comments:
            into["comments"] = sorted(comments, key=lambda c: c["at"])
        if alarm.get("since") and (not into.get("since") or alarm["since"] < into["since"]):
            into["since"] = alarm["since"]
        if alarm.get("last_seen") and (into.get("last_seen") or "") < alarm["last_seen"]:
            into["last_seen"] = alarm["last_seen"]
        acks = [a for a in (into.get("acknowledged"), alarm.get("acknowledged")) if a]
        into["acknowledged"] = min(acks, key=lambda a: a["at"]) if acks else None
        for old in (alarm["id"], *alarm.get("merged", [])):
            moved[old] = into["id"]
    return kept, moved


def upgrade() -> None:
    op.create_table(
        "alarm_aliases",
        sa.Column("old_id", sa.String(16), primary_key=True),
        sa.Column("alarm_id", sa.String(16), nullable=False),
    )
    op.create_index("ix_alarm_aliases_alarm_id", "alarm_aliases", ["alarm_id"])
    states = sa.table(
        "monitor_states",
        sa.column("conveyor_id", sa.String(200)),
        sa.column("state", sa.JSON()),
    )
    alarms = sa.table(
        "alarms",
        sa.column("id", sa.String(16)),
        sa.column("since", sa.String(40)),
        sa.column("content", sa.JSON()),
    )
    aliases = sa.table(
        "alarm_aliases", sa.column("old_id", sa.String(16)), sa.column("alarm_id", sa.String(16))
    )
    bind = op.get_bind()
    for conveyor, state in bind.execute(sa.select(states.c.conveyor_id, states.c.state)).all():
        if not isinstance(state, dict) or not isinstance(state.get("alarms"), list):
            continue
        grouped, moved = _group(state["alarms"])
        if not moved:
            continue
        bind.execute(
            states.update()
            .where(states.c.conveyor_id == conveyor)
            .values(state=dict(state, alarms=grouped))
        )
        by_id = {a["id"]: a for a in grouped}
        for new in set(moved.values()):
            content = dict(by_id[new], conveyor=conveyor)
            bind.execute(
                alarms.update()
                .where(alarms.c.id == new)
                .values(content=content, since=content.get("since"))
            )
        bind.execute(alarms.delete().where(alarms.c.id.in_(list(moved))))
        bind.execute(aliases.insert(), [{"old_id": o, "alarm_id": n} for o, n in moved.items()])


def downgrade() -> None:
    # grouped alarms stay grouped (the former code reads them as alarms of their lead feature)
    op.drop_index("ix_alarm_aliases_alarm_id", table_name="alarm_aliases")
    op.drop_table("alarm_aliases")
