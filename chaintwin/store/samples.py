"""A recording's samples as the store keeps them and as workers send them.

:func:`pack_channels` packs the channels losslessly: their bytes one
channel after the other behind a small JSON header (names, dtypes,
lengths), compressed with Zstandard. A 2048-sample scope of eight float64
channels (131 kB) packs to about 40 kB in about 0.25 ms. The bytes are not
shuffled by byte position (the filter of array compressors): samples
converted to SI from quantised file units have noisy mantissas, what
compresses is repeated values (set points, standstill), and shuffling
measured worse (49 kB against 39 kB for the same scope).

:class:`PackedChannels` is a recording's channel mapping that travels
packed: a worker process packs the channels once for the store, and the
recording it sends back carries those bytes, and unpacked only the channels
that the health model reads (:data:`SENT_UNPACKED`); whoever reads another
channel gets it unpacked on first use, exactly. Once a recording's features
are computed, the health model reads only its time and speed (the belt
travel of the usage) and the store its packed bytes, so the ingest's
coordinating process never unpacks.
"""

from __future__ import annotations

import io
import json
import struct
import threading
import zlib
from collections.abc import Iterator, Mapping
from datetime import datetime
from typing import Any

import numpy as np
import numpy.typing as npt
import zstandard

from chaintwin.diagnose.state import json_ready
from chaintwin.errors import StoreError
from chaintwin.read.recording import Metadata, Recording, RecordingWarning

__all__ = [
    "SAMPLES_ZSTD_LEVEL",
    "SENT_UNPACKED",
    "PackedChannels",
    "load_samples",
    "pack_channels",
    "pack_samples",
    "recording_meta",
    "stored_recording",
    "unpack_channels",
]

SAMPLES_ZSTD_LEVEL = 1
"""Zstandard level of the packed samples.

Level 1 against 3, measured on 200 virtual white-belt-01 scopes (2048
samples, 8 channels): 39.9 kB against 39.2 kB per recording (+1.9 %),
0.25 ms against 0.35 ms to pack. Any level reads back the same."""

SENT_UNPACKED = ("time", "speed")
"""Channels a :class:`PackedChannels` carries unpacked beside its packed bytes.

What the health model reads of a recording whose features a worker
computed (the belt travel ``∫|ω|·r/i dt`` of the usage): the ingest's
process then does not unpack the recording (decompress and copy all its
channels, about 0.3 ms) for two of them. They add 32 kB to the 40 kB a
2048-sample recording travels as."""

_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
_FORMAT = b"CTS1"
"""First bytes of the (decompressed) packing of :func:`pack_channels`."""
_HEAD = struct.Struct("<I")
_DTYPES_KEY = "__dtypes__"
"""The dtypes entry of an earlier ``.npz`` packing (transposed byte views in an archive)."""

Array = npt.NDArray[Any]


def pack_channels(channels: Mapping[str, npt.ArrayLike]) -> bytes:
    """Channels (name -> 1-D array), packed losslessly for the store.

    Parameters
    ----------
    channels : Mapping[str, array_like]
        1-D arrays of any numeric dtype, any lengths.

    Returns
    -------
    bytes
        A Zstandard frame; :func:`unpack_channels` gives the arrays back,
        bit for bit, with their dtypes.
    """
    arrays = [(name, np.ascontiguousarray(values)) for name, values in channels.items()]
    for name, a in arrays:
        if a.ndim != 1:
            raise ValueError(f"channel '{name}' is not one-dimensional (shape {a.shape})")
    header = json.dumps([[name, a.dtype.str, a.shape[0]] for name, a in arrays]).encode()
    total = sum(a.nbytes for _n, a in arrays)
    start = len(_FORMAT) + _HEAD.size + len(header)
    out = np.empty(start + total, dtype=np.uint8)
    out[:start] = np.frombuffer(_FORMAT + _HEAD.pack(len(header)) + header, dtype=np.uint8)
    at = start
    for _name, a in arrays:
        out[at : at + a.nbytes] = a.view(np.uint8)
        at += a.nbytes
    compressed: bytes = _compressor().compress(out.data)
    return compressed


_LOCAL = threading.local()


def _compressor() -> zstandard.ZstdCompressor:
    """This thread's compressor at :data:`SAMPLES_ZSTD_LEVEL` (the same frames as a new
    one each time, without its set-up; a compressor is not shared between threads)."""
    c: zstandard.ZstdCompressor | None = getattr(_LOCAL, "compressor", None)
    if c is None:
        c = _LOCAL.compressor = zstandard.ZstdCompressor(level=SAMPLES_ZSTD_LEVEL)
    return c


def unpack_channels(blob: bytes) -> dict[str, Array]:
    """The channels packed by :func:`pack_channels`, or by earlier versions of the store.

    Earlier stores hold an ``.npz`` archive: compressed by numpy, by zlib,
    or byte-shuffled and compressed by Zstandard; all are read.

    Raises
    ------
    StoreError
        When the bytes are none of these (a damaged store).
    """
    try:
        if blob[:4] == _ZSTD_MAGIC:
            raw = zstandard.ZstdDecompressor().decompress(blob)
        elif blob[:2] == b"PK":  # numpy's compressed .npz
            raw = blob
        else:  # zlib-compressed .npz
            raw = zlib.decompress(blob)
        if raw[: len(_FORMAT)] == _FORMAT:
            return _unpack(raw)
        return _unpack_npz(raw)
    except (
        zstandard.ZstdError,
        zlib.error,
        struct.error,
        ValueError,
        TypeError,
        KeyError,
        OSError,
    ) as exc:
        raise StoreError(
            f"stored samples cannot be unpacked ({exc}); the store is damaged"
        ) from None


def _unpack(raw: bytes) -> dict[str, Array]:
    (size,) = _HEAD.unpack_from(raw, len(_FORMAT))
    at = len(_FORMAT) + _HEAD.size
    header = json.loads(raw[at : at + size])
    at += size
    buf = np.frombuffer(raw, dtype=np.uint8)
    out: dict[str, Array] = {}
    for name, dtype_str, n in header:
        dtype = np.dtype(dtype_str)
        size = n * dtype.itemsize
        block = buf[at : at + size]
        if block.shape[0] != size:
            raise ValueError(f"channel '{name}' is cut short")
        out[str(name)] = block.copy().view(dtype)  # a copy: writable, owns its memory
        at += size
    return out


def _unpack_npz(raw: bytes) -> dict[str, Array]:
    with np.load(io.BytesIO(raw)) as data:
        stored = {k: data[k] for k in data.files}
    dtypes = json.loads(str(stored.pop(_DTYPES_KEY))) if _DTYPES_KEY in stored else {}
    for name, dtype in dtypes.items():
        stored[name] = np.ascontiguousarray(stored[name].T).view(np.dtype(dtype)).ravel()
    return stored


class PackedChannels(Mapping[str, Array]):
    """A recording's channels that travel packed and unpack on first use.

    Parameters
    ----------
    names : tuple of str
        The channel names, in order.
    blob : bytes
        The channels packed by :func:`pack_channels`.
    arrays : Mapping[str, ndarray], optional
        The channels themselves, when at hand (the process that packed
        them): nothing is unpacked then. Never pickled whole.
    loose : Mapping[str, ndarray], optional
        Some of the channels, carried unpacked (:data:`SENT_UNPACKED`):
        reading them unpacks nothing.

    Notes
    -----
    Names, length and membership are answered without unpacking; reading a
    channel not carried loose unpacks all of them once. Pickling sends the
    names, the packed bytes and the channels of :data:`SENT_UNPACKED`.
    """

    __slots__ = ("_arrays", "_loose", "blob", "names")

    def __init__(
        self,
        names: tuple[str, ...],
        blob: bytes,
        arrays: Mapping[str, Array] | None = None,
        loose: Mapping[str, Array] | None = None,
    ) -> None:
        self.names = names
        self.blob = blob
        self._arrays = None if arrays is None else dict(arrays)
        self._loose = dict(loose or {})

    @classmethod
    def of(cls, channels: Mapping[str, npt.ArrayLike]) -> PackedChannels:
        """Pack ``channels``, keeping the arrays at hand."""
        arrays = {name: np.asarray(values) for name, values in channels.items()}
        return cls(tuple(arrays), pack_channels(arrays), arrays)

    @property
    def unpacked(self) -> bool:
        """Whether all the arrays are at hand (given, or unpacked by a read)."""
        return self._arrays is not None

    def __getitem__(self, key: str) -> Array:
        if key not in self.names:
            raise KeyError(key)
        if self._arrays is None:
            loose = self._loose.get(key)
            if loose is not None:
                return loose
            self._arrays = unpack_channels(self.blob) | self._loose  # the same arrays
        return self._arrays[key]

    def __contains__(self, key: object) -> bool:
        return key in self.names

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def __reduce__(
        self,
    ) -> tuple[type[PackedChannels], tuple[tuple[str, ...], bytes, None, dict[str, Array]]]:
        at_hand = self._loose if self._arrays is None else self._arrays
        loose = {k: at_hand[k] for k in SENT_UNPACKED if k in at_hand}
        return (PackedChannels, (self.names, self.blob, None, loose))


# ---------------------------------------------------------------- recordings
def pack_samples(recording: Recording) -> bytes:
    """The channels (SI) of a recording, packed losslessly for the store (:mod:`.samples`)."""
    channels = recording.channels
    if isinstance(channels, PackedChannels):  # packed already (in a worker)
        return channels.blob
    return pack_channels(channels)


def load_samples(blob: bytes) -> dict[str, np.ndarray]:
    """The channels (SI) of a stored recording, in any packing the store has used."""
    return unpack_channels(blob)


def recording_meta(recording: Recording) -> dict[str, Any]:
    """A recording's metadata and channel units, JSON-ready, as stored."""
    m = recording.metadata
    out: dict[str, Any] = {
        k: getattr(m, k)
        for k in ("conveyor", "sample_time_s", "payload_kg", "tray_kg")
        if getattr(m, k, None) is not None
    }
    if m.recorded_at is not None:
        out["recorded_at"] = m.recorded_at.isoformat()
    out["extra"] = dict(m.extra)
    out["units"] = dict(recording.si_units())
    return json_ready(out)  # type: ignore[no-any-return]


def stored_recording(
    file: str, meta: dict[str, Any], warnings: list[Any], samples: bytes
) -> Recording:
    """Rebuild a :class:`Recording` from what the store keeps of it.

    Raises
    ------
    StoreError
        When its samples were dropped by retention (``serve --keep-samples-days``).
    """
    if not samples:
        raise StoreError(
            f"{file}: its samples were dropped by retention (serve --keep-samples-days); "
            "its result is kept, the recording itself is gone"
        )
    at = meta.get("recorded_at")
    metadata = Metadata(
        conveyor=meta.get("conveyor"),
        recorded_at=None if at is None else datetime.fromisoformat(at),
        sample_time_s=meta.get("sample_time_s"),
        payload_kg=meta.get("payload_kg"),
        tray_kg=meta.get("tray_kg"),
        extra=dict(meta.get("extra", {})),
    )
    channels = load_samples(samples)
    units = dict(meta.get("units", {}))
    return Recording(
        source=file,
        channels=channels,
        units={k: units.get(k, "") for k in channels},
        headers={k: k for k in channels},
        metadata=metadata,
        warnings=tuple(RecordingWarning(str(w["code"]), str(w["message"])) for w in warnings),
    )
