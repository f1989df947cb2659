"""Property tests: whatever the reader is fed, it fails only with its own data error."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chaintwin import RecordingError, inspect_recording, parse_recording

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def parse_and_inspect(data: str | bytes) -> None:
    try:
        rec = parse_recording(data, "fuzz.csv")
    except RecordingError as exc:
        assert str(exc).startswith("fuzz.csv")
        return
    inspect_recording(rec)  # a recording that was accepted is inspected without error


@FUZZ
@given(st.binary(max_size=4000))
def test_arbitrary_bytes(data: bytes) -> None:
    parse_and_inspect(data)


@FUZZ
@given(st.text(max_size=4000))
def test_arbitrary_text(data: str) -> None:
    parse_and_inspect(data)


CELL = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**25), 10**25).map(str),
    st.sampled_from(["", " ", "-", "1e400", "1,5", "nan", "x", "0x10", "1_0", "--1", "1e", "."]),
    st.text(alphabet="0123456789.,;-+eE ", max_size=8),
)
HEADERS = st.lists(
    st.sampled_from(
        [
            "time [s]",
            "time [ms]",
            "speed [rpm]",
            "speed [rad/s]",
            "torque [Nm]",
            "torque [%]",
            "position [inc]",
            "position [rev]",
            "speed_setpoint [1/min]",
            "torque_setpoint [%]",
            "digital_inputs [-]",
            "extra [V]",
            "time [h]",
            "speed",
        ]
    ),
    min_size=1,
    max_size=8,
)


@FUZZ
@given(
    headers=HEADERS,
    rows=st.lists(st.lists(CELL, min_size=1, max_size=9), min_size=0, max_size=60),
    sep=st.sampled_from([",", ";"]),
    meta=st.lists(
        st.tuples(
            st.sampled_from(
                [
                    "conveyor",
                    "recorded_at",
                    "sample_time_s",
                    "nominal_torque_nm",
                    "increments_per_rev",
                    "payload_kg",
                    "tray_kg",
                    "other",
                ]
            ),
            st.text(max_size=20).filter(lambda s: "\n" not in s and "\r" not in s),
        ),
        max_size=5,
    ),
)
def test_structured_garbage(
    headers: list[str], rows: list[list[str]], sep: str, meta: list[tuple[str, str]]
) -> None:
    lines = [f"# {k}: {v}" for k, v in meta]
    lines.append(sep.join(headers))
    lines.extend(sep.join(r) for r in rows)
    parse_and_inspect("\n".join(lines))


@FUZZ
@given(
    n=st.integers(32, 300),
    speed=st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=5),
    dt=st.floats(1e-4, 1.0),
    jitter=st.floats(0.0, 0.5),
)
def test_valid_numbers_in_odd_shapes_are_accepted_or_refused_cleanly(
    n: int, speed: list[float], dt: float, jitter: float
) -> None:
    lines = ["time [s],speed_setpoint [rpm],speed [rpm],torque_setpoint [Nm],torque [Nm]"]
    t = 0.0
    for k in range(n):
        s = speed[k % len(speed)]
        lines.append(f"{t!r},{s!r},{s * 0.99!r},{s / 1e3!r},{s / 1e3!r}")
        t += dt * (1.0 + jitter * ((k * 7919) % 13) / 13.0)
    parse_and_inspect("\n".join(lines))
