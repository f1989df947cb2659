"""The default OPC UA node layout of a drive's scope buffer (docs/opcua.md).

One object ``Scope`` per drive, in the namespace :data:`NAMESPACE_URI`, with
string node ids ``Scope.<Name>``:

* the channels, one ``Double`` array each (``Speed``, ``Position``,
  ``TorqueSetpoint``, ...), in the drive's own units; each channel has a
  ``String`` child ``<channel>.Unit`` naming its unit as the data contract
  spells it (``rpm``, ``inc``, ``%``, ...);
* the scope's metadata: ``SampleTime`` (``Double``, s), ``TriggerTime``
  (``DateTime``, UTC), ``ConveyorId`` (``String``), ``NominalTorque``
  (``Double``, Nm: for ``%`` torques) and ``IncrementsPerRev`` (``Double``:
  for ``inc`` positions);
* ``Counter`` (``UInt32``): incremented once per new scope, written after
  every other node of that scope. 0: no scope yet.

The time channel is not published: sample *k* is at ``k * SampleTime``
after the trigger, as in a drive's scope buffer.

The drive simulator (:mod:`chaintwin.live.drive_sim`) serves this layout and
the client (:mod:`chaintwin.live.opcua`) reads it unless a drive's
configuration names other node ids.
"""

from __future__ import annotations

from typing import Final

__all__ = [
    "CHANNEL_KEYS",
    "DEFAULT_NODES",
    "METADATA_KEYS",
    "NAMESPACE_URI",
    "OBJECT_NAME",
    "default_node_id",
    "unit_key",
]

NAMESPACE_URI: Final = "urn:chaintwin:drive-scope"
"""Namespace of the default layout's nodes (its index is looked up on connect)."""

OBJECT_NAME: Final = "Scope"
"""Browse name of the object that holds a drive's scope buffer."""

#: Channel key (the data contract's canonical name) → node name in the default layout.
CHANNEL_KEYS: Final[dict[str, str]] = {
    "speed_setpoint": "SpeedSetpoint",
    "speed": "Speed",
    "position_setpoint": "PositionSetpoint",
    "position": "Position",
    "torque_setpoint": "TorqueSetpoint",
    "torque": "Torque",
    "digital_inputs": "DigitalInputs",
}

#: Metadata key → node name in the default layout.
METADATA_KEYS: Final[dict[str, str]] = {
    "counter": "Counter",
    "conveyor_id": "ConveyorId",
    "trigger_time": "TriggerTime",
    "sample_time": "SampleTime",
    "nominal_torque": "NominalTorque",
    "increments_per_rev": "IncrementsPerRev",
}


def unit_key(channel: str) -> str:
    """The ``nodes`` key of a channel's unit node (``speed`` → ``speed_unit``)."""
    return f"{channel}_unit"


def default_node_id(name: str) -> str:
    """The default layout's node id for a node name, namespace given by URI.

    ``Speed`` → ``nsu=urn:chaintwin:drive-scope;s=Scope.Speed``.
    """
    return f"nsu={NAMESPACE_URI};s={OBJECT_NAME}.{name}"


#: ``nodes`` key → default node id, every key a configuration may override.
DEFAULT_NODES: Final[dict[str, str]] = {
    **{key: default_node_id(name) for key, name in METADATA_KEYS.items()},
    **{key: default_node_id(name) for key, name in CHANNEL_KEYS.items()},
    **{unit_key(key): default_node_id(f"{name}.Unit") for key, name in CHANNEL_KEYS.items()},
}
