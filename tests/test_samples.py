"""Samples packed for the store and for the way back from a worker process."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE

from chaintwin.errors import StoreError
from chaintwin.ingest.worker import prepare
from chaintwin.read.profile import load_profile
from chaintwin.store.samples import (
    SENT_UNPACKED,
    PackedChannels,
    pack_channels,
    unpack_channels,
)
from chaintwin.validate.checks import load_recording

REC = EXAMPLES / "recordings" / "white-belt-01-40kg.csv"


def test_mixed_dtypes_and_lengths_round_trip_bit_for_bit() -> None:
    rng = np.random.default_rng(1)
    channels = {
        "time": np.arange(7) * 0.006,
        "torque": rng.standard_normal(7),
        "digital_inputs": np.array([0, 1, 3, 3, 0, 2**40, -5], dtype=np.int64),
        "extra [V]": rng.standard_normal(3).astype(np.float32),
        "flags": np.array([1, 0, 1], dtype=np.uint8),
        "empty": np.array([], dtype=np.float64),
        "special": np.array([np.nan, np.inf, -0.0, 5e-324]),
    }
    got = unpack_channels(pack_channels(channels))
    assert list(got) == list(channels)
    for name, a in channels.items():
        assert got[name].dtype == a.dtype, name
        assert got[name].tobytes() == a.tobytes(), name  # NaN payload and -0.0 too
        assert got[name].flags.writeable and got[name].flags.c_contiguous


def test_a_damaged_packing_is_a_store_error() -> None:
    blob = pack_channels({"time": np.arange(10.0)})
    with pytest.raises(StoreError, match="damaged"):
        unpack_channels(blob[:-5])
    with pytest.raises(StoreError, match="damaged"):
        unpack_channels(b"neither zstd nor zip")
    import zstandard

    with pytest.raises(StoreError, match="damaged"):  # the header cut inside its length
        unpack_channels(zstandard.ZstdCompressor().compress(b"CTS1\x05"))
    with pytest.raises(ValueError, match="one-dimensional"):
        pack_channels({"x": np.zeros((2, 2))})


def test_packed_channels_travel_at_a_third_and_unpack_exactly_on_first_read() -> None:
    rec = load_recording(REC).recording
    packed = PackedChannels.of(rec.channels)
    raw = sum(np.asarray(v).nbytes for v in rec.channels.values())
    loose = sum(np.asarray(rec.channels[k]).nbytes for k in SENT_UNPACKED)
    wire = pickle.dumps(packed)
    assert len(wire) < 0.4 * raw + loose  # a third, and the channels sent unpacked
    back = pickle.loads(wire)
    assert isinstance(back, PackedChannels) and not back.unpacked
    # names, membership and length need no unpacking, nor the channels sent unpacked
    assert list(back) == list(rec.channels) and len(back) == len(rec.channels)
    assert "position" in back and "nope" not in back and back.get("nope") is None
    for name in SENT_UNPACKED:
        np.testing.assert_array_equal(back[name], rec.channels[name])
    assert not back.unpacked
    again = pickle.loads(pickle.dumps(back))  # passed on before it is unpacked
    np.testing.assert_array_equal(again["speed"], rec.channels["speed"])
    assert not again.unpacked
    for name, a in rec.channels.items():
        np.testing.assert_array_equal(back[name], a)
    assert back.unpacked


def test_prepare_sends_the_recording_packed_with_the_bytes_the_store_keeps() -> None:
    item = prepare(str(REC), load_profile(REFERENCE_PROFILE), None, None)
    assert item.recording is not None and item.samples is not None
    channels = item.recording.channels
    assert isinstance(channels, PackedChannels) and channels.blob is item.samples
    back = pickle.loads(pickle.dumps(item))
    assert back.recording is not None and back.samples is not None
    assert back.recording.channels.blob == back.samples  # sent once (pickle's memo)
    loose = sum(channels[k].nbytes for k in SENT_UNPACKED)
    assert len(pickle.dumps(item)) < 1.1 * len(item.samples) + loose + 20_000
    plain = load_recording(REC, profile=load_profile(REFERENCE_PROFILE)).recording
    for name in plain.channels:
        np.testing.assert_array_equal(back.recording.channels[name], plain.channels[name])
