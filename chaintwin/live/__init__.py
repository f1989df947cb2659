"""The live service: recordings followed as they happen (watched folders, drives over OPC UA)."""
