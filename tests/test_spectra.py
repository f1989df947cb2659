"""Spectra: amplitude scale, order analysis on a ramp, folding, novel peaks, the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin._types import FloatArray
from chaintwin.cli.app import main
from chaintwin.diagnose.lines import band_amplitude, line_amplitudes
from chaintwin.diagnose.peaks import median_spectrum, novel_peaks, strongest_peaks
from chaintwin.diagnose.spectra import Spectrum, order_spectrum, welch_spectrum
from chaintwin.errors import EstimationError, RecordingError, StoreError
from chaintwin.model.frequencies import (
    apparent_order,
    apparent_orders,
    characteristic_orders,
    line_orders,
)
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.read.recording import Metadata, Recording
from chaintwin.read.writer import write_recording
from chaintwin.report.spectrum_plot import plot_spectrum
from chaintwin.simulate.faults import BEARING_ORDER, Fault
from chaintwin.simulate.virtual import run_virtual
from chaintwin.units import RPM_TO_RAD_S

NOMINAL_RPM = 1415.0
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def make_recording(channels: dict[str, FloatArray]) -> Recording:
    """An in-memory SI recording of the given channels."""
    units = {"time": "s", "speed": "rad/s", "position": "rad", "torque": "Nm"}
    return Recording(
        source="<synthetic>",
        channels=channels,
        units={n: units.get(n, "-") for n in channels},
        headers={n: n for n in channels},
        metadata=Metadata(),
    )


def ramp_recording(
    *,
    order: float = 2.5,
    amplitude: float = 0.1,
    n: int = 2048,
    dt: float = 0.001,
    with_position: bool = True,
    direction: int = 1,
    wrapped: bool = False,
    seed: int = 0,
) -> Recording:
    """Speed ramping from 40 % to 100 % of 1415 rpm over the record; a torque line at ``order``.

    The torque also follows the ramp (a slow trend) and holds a little noise;
    the position is the exact motor angle counted in whole 4096-increment steps.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    w0, w1 = 0.4 * NOMINAL_RPM * RPM_TO_RAD_S, NOMINAL_RPM * RPM_TO_RAD_S
    theta = w0 * t + 0.5 * (w1 - w0) * t**2 / t[-1]  # exact angle travelled, rad
    speed = w0 + (w1 - w0) * t / t[-1]
    torque = 1.2 + 0.4 * t / t[-1] + amplitude * np.sin(order * theta)
    channels: dict[str, FloatArray] = {
        "time": t,
        "speed": direction * (speed + rng.normal(0.0, 0.8 * RPM_TO_RAD_S, n)),
        "torque": direction * torque + rng.normal(0.0, 0.005, n),
    }
    if with_position:
        inc = 2.0 * math.pi / 4096
        channels["position"] = np.floor((1234.5 + direction * theta) / inc) * inc
        if wrapped:  # a single-turn position: disagrees with the speed, which is used instead
            channels["position"] = np.mod(channels["position"], 2.0 * math.pi)
    return make_recording(channels)


def sine_recording(
    freq_hz: float, amplitude: float, *, n: int = 2048, dt: float = 0.006
) -> Recording:
    """Constant speed, torque = offset + a pure sinusoid."""
    t = np.arange(n) * dt
    return make_recording(
        {
            "time": t,
            "speed": np.full(n, 1000.0 * RPM_TO_RAD_S),
            "torque": 2.0 + amplitude * np.sin(2.0 * math.pi * freq_hz * t + 0.7),
        }
    )


@pytest.fixture(scope="module")
def profile() -> ConveyorProfile:
    return load_profile(REFERENCE_PROFILE)


# ------------------------------------------------------------------ amplitude scale
@pytest.mark.parametrize("freq_hz", [25.0, 31.37, 62.5])
def test_welch_amplitude_of_a_pure_sinusoid(freq_hz: float) -> None:
    amplitude = 0.2
    spec = welch_spectrum(sine_recording(freq_hz, amplitude))
    assert spec.kind == "frequency"
    assert spec.channel == "torque"
    assert spec.speed_rpm == pytest.approx(1000.0)
    assert spec.x[0] == 0.0 and spec.x[-1] == pytest.approx(0.5 / 0.006)
    assert np.diff(spec.x) == pytest.approx(spec.resolution)
    x, peak = strongest_peaks(spec, top=1)[0]
    assert abs(x - freq_hz) <= spec.resolution
    assert peak == pytest.approx(amplitude, rel=0.05)
    assert band_amplitude(spec, freq_hz) == pytest.approx(amplitude, rel=0.05)


def test_welch_default_nperseg_and_options() -> None:
    rec = sine_recording(25.0, 0.2)
    default = welch_spectrum(rec, span=(0, 2048))
    # 2048 samples: 512-sample segments (7 averages at 50 % overlap), zero-padded ×2
    assert default.resolution == pytest.approx(1.0 / (1024 * 0.006))
    assert welch_spectrum(rec, nperseg=64).resolution == pytest.approx(1.0 / (128 * 0.006))
    with pytest.raises(EstimationError, match="span"):
        welch_spectrum(rec, span=(100, 110))
    with pytest.raises(EstimationError, match="nperseg"):
        welch_spectrum(rec, nperseg=4096)
    with pytest.raises(RecordingError, match="no channel 'current'"):
        welch_spectrum(rec, "current")


# ------------------------------------------------------------------ order analysis
@pytest.mark.parametrize(
    ("with_position", "direction", "wrapped"),
    [(True, 1, False), (False, 1, False), (True, -1, False), (True, 1, True)],
    ids=["position", "integrated-speed", "backward", "wrapped-position"],
)
def test_order_spectrum_holds_a_line_still_on_a_ramp(
    with_position: bool, direction: int, wrapped: bool
) -> None:
    amplitude = 0.1
    rec = ramp_recording(
        amplitude=amplitude, with_position=with_position, direction=direction, wrapped=wrapped
    )
    spec = order_spectrum(rec)
    assert spec.kind == "order"
    # mean of a 40 %..100 % linear ramp
    assert spec.speed_rpm == pytest.approx(0.7 * NOMINAL_RPM, rel=0.01)
    above = spec.x > 0.5  # past the trend's leakage
    k = int(np.argmax(np.where(above, spec.amplitude, 0.0)))
    assert abs(spec.x[k] - 2.5) <= spec.resolution
    assert spec.amplitude[k] == pytest.approx(amplitude, rel=0.15)
    assert band_amplitude(spec, 2.5) == pytest.approx(amplitude, rel=0.15)

    # a plain FFT of the same record smears the line over the speed range
    plain = welch_spectrum(rec, span=(0, rec.samples))
    assert float(np.max(plain.amplitude[plain.x > 5.0])) < 0.5 * amplitude


def test_order_spectrum_refuses_standstill_and_bad_options() -> None:
    rec = ramp_recording()
    still = make_recording({**rec.channels, "speed": np.zeros(rec.samples)})
    with pytest.raises(EstimationError, match="does not turn"):
        order_spectrum(still)
    with pytest.raises(EstimationError, match="min_speed_share"):
        order_spectrum(rec, min_speed_share=0.0)
    with pytest.raises(EstimationError, match="oversample"):
        order_spectrum(rec, oversample=-1.0)
    finer = order_spectrum(rec, oversample=2.0)
    assert finer.x[-1] == pytest.approx(2.0 * order_spectrum(rec).x[-1], rel=0.01)


# ------------------------------------------------------------------ folding
def test_apparent_orders_equal_apparent_order_of_each() -> None:
    rng = np.random.default_rng(7)
    orders = np.concatenate(([0.0, 1.0, 3.57, 10.0], rng.uniform(0.0, 400.0, 500)))
    for speed in (1415.0, -700.0, 37.5):
        for ts in (0.001, 0.006, 0.012, 0.0123):
            got = apparent_orders(orders, speed, ts)
            want = [apparent_order(float(o), speed, ts) for o in orders]
            assert got.tolist() == want  # the same arithmetic: equal to the last bit
    with pytest.raises(EstimationError, match="rotation"):
        apparent_orders(orders, 0.0, 0.006)


def test_apparent_order_hand_case() -> None:
    # 3.57 × 1415/60 = 84.19 Hz; a 6 ms scope's Nyquist is 83.33 Hz: it shows at 82.47 Hz
    rot_hz = NOMINAL_RPM / 60.0
    folded = apparent_order(3.57, NOMINAL_RPM, 0.006)
    assert folded * rot_hz == pytest.approx(2 * 83.3333 - 84.1925, abs=1e-3)
    assert folded == pytest.approx(3.4971, abs=1e-4)
    assert apparent_order(3.57, -NOMINAL_RPM, 0.001) == pytest.approx(3.57)  # below Nyquist
    # 12 ms: 84.19 Hz - 83.33 Hz (fs) = 0.86 Hz
    assert apparent_order(3.57, NOMINAL_RPM, 0.012) * rot_hz == pytest.approx(0.859, abs=1e-3)
    with pytest.raises(EstimationError, match="rotation"):
        apparent_order(3.57, 0.0, 0.006)


def test_band_amplitude_window_and_range() -> None:
    x = np.arange(11, dtype=np.float64)
    amp = np.zeros(11)
    amp[7] = 5.0
    spec = Spectrum(x, amp, "frequency", 1.0, "torque", 1000.0)
    assert band_amplitude(spec, 5.0) == 5.0
    assert band_amplitude(spec, 4.0) == 0.0
    assert band_amplitude(spec, 4.0, half_width_bins=3) == 5.0
    assert band_amplitude(spec, 10.4) == 0.0
    assert band_amplitude(spec, -1.0) == 0.0
    assert band_amplitude(spec, 11.0) == 0.0


# ------------------------------------------------------------------ baseline and novelty
def test_novel_peaks_and_median_spectrum() -> None:
    x = np.linspace(0.0, 10.0, 101)
    base = np.full(101, 0.01)
    base[30] = 1.0  # a line every spectrum has

    def spec(amp: FloatArray, grid: FloatArray = x) -> Spectrum:
        return Spectrum(grid, amp, "order", float(grid[1] - grid[0]), "torque", 1400.0)

    shifted = np.linspace(0.0, 10.0, 201)
    ref = median_spectrum(
        [spec(base), spec(base * 1.1), spec(np.interp(shifted, x, base * 0.9), shifted)]
    )
    assert ref.x is not x and np.array_equal(ref.x, x)
    assert ref.amplitude == pytest.approx(base)

    new = base.copy()
    new[60] = 0.2  # a new line, 20 × the floor
    new[80] = 0.02  # 2 ×: below min_ratio
    peaks = novel_peaks(spec(new), ref)
    assert [(round(px, 6), round(pa, 6)) for px, pa, _ in peaks] == [(6.0, 0.2)]
    assert peaks[0][2] == pytest.approx(20.0)
    assert novel_peaks(spec(base), ref) == []

    freq = Spectrum(x, base, "frequency", 0.1, "torque", 1400.0)
    with pytest.raises(EstimationError, match="different kinds"):
        novel_peaks(freq, ref)
    with pytest.raises(EstimationError, match="no spectrum"):
        median_spectrum([])


def test_bearing_fault_is_a_novel_peak_where_it_folds(profile: ConveyorProfile) -> None:
    ts = 0.006  # the bearing line (84.2 Hz) lies above the 83.3 Hz Nyquist frequency

    def recording(seed: int, faults: list[Fault]) -> Recording:
        run = run_virtual(profile, payload_kg=20.0, sample_time_s=ts, faults=faults, seed=seed)
        return run.recording

    baseline = median_spectrum([welch_spectrum(recording(s, [])) for s in (1, 2, 3)])
    faulty_rec = recording(10, [Fault("bearing", 1.0)])
    healthy_rec = recording(11, [])

    def novel_orders(rec: Recording) -> tuple[float, list[float]]:
        spec = welch_spectrum(rec)
        rot_hz = spec.speed_rpm / 60.0
        where = apparent_order(BEARING_ORDER, spec.speed_rpm, ts)
        tolerance = 2.0 * spec.resolution / rot_hz  # two bins, in orders
        found = [x / rot_hz for x, _, _ in novel_peaks(spec, baseline, min_ratio=4.0)]
        return where, [o for o in found if abs(o - where) <= tolerance]

    where, faulty = novel_orders(faulty_rec)
    assert where == pytest.approx(3.497, abs=0.005)  # not at 3.57: folded
    assert len(faulty) == 1
    assert novel_orders(healthy_rec)[1] == []

    faulty_lines = line_amplitudes(faulty_rec, profile)
    healthy_lines = line_amplitudes(healthy_rec, profile)
    names = [*characteristic_orders(profile), "sprocket_tooth_pass_h2", "sprocket_tooth_pass_h3"]
    assert list(faulty_lines) == names == list(line_orders(profile))
    assert all(math.isfinite(v) and v >= 0.0 for v in faulty_lines.values())
    # the polygon effect's tooth pass is there in both, the same size (Nm)
    assert healthy_lines["sprocket_tooth_pass"] > 0.02
    assert faulty_lines["sprocket_tooth_pass"] == pytest.approx(
        healthy_lines["sprocket_tooth_pass"], rel=0.2
    )


def test_line_amplitudes_need_rotation(profile: ConveyorProfile) -> None:
    n = 512
    still = make_recording(
        {"time": np.arange(n) * 0.006, "speed": np.zeros(n), "torque": np.full(n, 0.1)}
    )
    with pytest.raises(EstimationError, match="speed-locked lines need it to turn"):
        line_amplitudes(still, profile)


# ------------------------------------------------------------------ plot
def test_plot_spectrum_writes_a_png(tmp_path: Path) -> None:
    spec = welch_spectrum(sine_recording(25.0, 0.2))
    out = plot_spectrum(spec, tmp_path / "s.png", lines={"rotor": 16.7, "far": 1e6}, title="t")
    assert out == tmp_path / "s.png"
    assert out.read_bytes().startswith(PNG_MAGIC)
    assert [p.name for p in tmp_path.iterdir()] == ["s.png"]  # no temporary left
    with pytest.raises(StoreError, match="cannot write the picture") as info:
        plot_spectrum(spec, tmp_path / "missing" / "s.png")
    assert info.value.field == "png"
    assert [p.name for p in tmp_path.iterdir()] == ["s.png"]


# ------------------------------------------------------------------ CLI
@pytest.fixture(scope="module")
def bearing_csv(tmp_path_factory: pytest.TempPathFactory, profile: ConveyorProfile) -> Path:
    run = run_virtual(
        profile, payload_kg=20.0, sample_time_s=0.006, faults=[Fault("bearing", 1.0)], seed=5
    )
    return write_recording(run.recording, tmp_path_factory.mktemp("rec") / "bearing.csv")


def test_cli_json_with_profile(bearing_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["spectrum", str(bearing_csv), "--profile", str(REFERENCE_PROFILE), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert {"file", "kind", "speed_rpm", "resolution", "lines", "peaks"} <= set(out)
    assert out["file"] == str(bearing_csv)
    assert out["kind"] == "frequency"
    assert out["speed_rpm"] == pytest.approx(NOMINAL_RPM, rel=0.01)
    assert out["resolution"] == pytest.approx(1.0 / (512 * 0.006))
    lines = {ln["name"]: ln for ln in out["lines"]}
    assert {"name", "order", "apparent", "amplitude"} <= set(lines["rotor"])
    mesh = lines["stage1_mesh"]  # order 12: 283 Hz, folded into [0, 83.3] Hz
    assert mesh["order"] == 12.0
    assert 0.0 <= mesh["apparent"] <= 0.5 / 0.006
    assert len(out["peaks"]) == 5
    amps = [p["amplitude"] for p in out["peaks"]]
    assert amps == sorted(amps, reverse=True)


def test_cli_orders_png_and_no_profile(
    bearing_csv: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    png = tmp_path / "order.png"
    code = main(["spectrum", str(bearing_csv), "--orders", "--png", str(png), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert out["kind"] == "order"
    assert out["lines"] == []
    assert png.read_bytes().startswith(PNG_MAGIC)


def test_cli_table_output(bearing_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["spectrum", str(bearing_csv), "--profile", str(REFERENCE_PROFILE)])
    text = capsys.readouterr().out
    assert code == 0
    assert "sprocket_tooth_pass" in text and "apparent [Hz]" in text
    assert "strongest peaks" in text


def test_cli_bad_file_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("time [h],speed [rpm],torque [Nm]\n0,0,0\n1,0,0\n", encoding="utf-8")
    code = main(["spectrum", str(bad), "--json"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1
    assert str(bad) in err


def test_cli_unwritable_png_is_one_line_exit_2(
    bearing_csv: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    png = tmp_path / "missing" / "s.png"
    code = main(["spectrum", str(bearing_csv), "--png", str(png)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "--png" in err and "cannot write the picture" in err
