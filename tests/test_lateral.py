"""Lateral (string) modes of the free strands and unresolvable lines on spectra."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import EXAMPLES, REFERENCE_PROFILE

from chaintwin.calibrating.procedure import calibrate
from chaintwin.cli.app import main
from chaintwin.diagnose.features import feature_spec, recording_features
from chaintwin.model.frequencies import (
    characteristic_lines,
    lateral_mode_hz,
    lateral_modes_note,
)
from chaintwin.read.profile import ConveyorProfile, load_profile
from chaintwin.read.writer import write_recording
from chaintwin.report import spectrum_plot
from chaintwin.report.spectrum_plot import _label_groups
from chaintwin.simulate import run_virtual
from chaintwin.simulate.fleet import generate
from chaintwin.validate import inspect_recording
from chaintwin.validate.checks import load_recording

WHITE = load_profile(REFERENCE_PROFILE)
SHORT = load_profile(EXAMPLES / "profiles" / "short-fast-03.yaml")


def _tensioned(profile: ConveyorProfile, tension_n: float) -> ConveyorProfile:
    belt = profile.belt.model_copy(update={"tension_n": tension_n})
    return profile.model_copy(update={"belt": belt})


@pytest.mark.parametrize(
    ("profile", "tension_n", "f1_hz"),
    [
        # L = 4.3 m, m' = 4.1 kg/m: 1/(2·4.3)·√(800/4.1) = 0.116279·13.96861
        (WHITE, 800.0, 1.624257),
        # L = 2.2 m, m' = 3.2 kg/m: 1/(2·2.2)·√(500/3.2) = 0.227273·12.5
        (SHORT, 500.0, 2.840909),
    ],
)
def test_lateral_modes_against_a_hand_calculation(
    profile: ConveyorProfile, tension_n: float, f1_hz: float
) -> None:
    prof = _tensioned(profile, tension_n)
    assert lateral_mode_hz(prof, 1) == pytest.approx(f1_hz, rel=1e-6)
    assert lateral_mode_hz(prof, 3) == pytest.approx(3 * f1_hz, rel=1e-6)
    lines = {ln.name: ln for ln in characteristic_lines(prof, 1400.0)}
    assert lines["lateral_mode_2"].frequency_hz == pytest.approx(2 * f1_hz, rel=1e-6)
    assert lines["lateral_mode_1"].kind == "structural"
    assert lines["lateral_mode_1"].order is None
    assert lateral_modes_note(prof) is None


def test_without_tension_the_lateral_modes_are_left_out_and_said_so() -> None:
    assert lateral_mode_hz(WHITE) is None
    assert not [ln for ln in characteristic_lines(WHITE, 1400.0) if "lateral" in ln.name]
    note = lateral_modes_note(WHITE)
    assert note is not None and "belt.tension_n" in note
    # the published "224 Hz": sqrt(K/m) with K = 1e6 N/m and m = 20 kg is rad/s
    assert math.sqrt(1e6 / 20.0) == pytest.approx(223.6, abs=0.05)
    assert math.sqrt(1e6 / 20.0) / (2 * math.pi) == pytest.approx(35.6, abs=0.05)


def test_spectrum_draws_the_lateral_mode_and_refuses_unresolvable_amplitudes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    prof = _tensioned(WHITE, 800.0)
    prof_path = tmp_path / "tensioned.yaml"
    prof_path.write_text(json.dumps(prof.model_dump(mode="json")))  # JSON is YAML
    run = run_virtual(WHITE, payload_kg=20.0, sample_time_s=0.006, seed=5)
    rec = write_recording(run.recording, tmp_path / "r.csv")
    drawn: dict[str, Any] = {}
    original = spectrum_plot.plot_spectrum

    def spy(spectrum: Any, path: Any, **kw: Any) -> Any:
        drawn.update(kw["lines"])
        drawn["_x_max"] = float(spectrum.x[-1])
        return original(spectrum, path, **kw)

    # the command imports the plot when it runs (a light --help): patch it at its home
    monkeypatch.setattr(spectrum_plot, "plot_spectrum", spy)
    png = tmp_path / "s.png"
    code = main(["spectrum", str(rec), "--profile", str(prof_path), "--png", str(png), "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    lines = {ln["name"]: ln for ln in out["lines"]}
    f1 = lateral_mode_hz(prof, 1)
    assert f1 is not None
    assert lines["lateral_mode_1"]["apparent"] == pytest.approx(f1)
    assert lines["lateral_mode_1"]["order"] is None
    assert "notes" not in out
    # drawn at its frequency with its name
    assert drawn["lateral_mode_1"] == pytest.approx(f1)
    labels = _label_groups({k: v for k, v in drawn.items() if k != "_x_max"}, drawn["_x_max"])
    assert any("lateral_mode_1" in label and x == pytest.approx(f1) for x, label in labels)
    # the belt revolution lies below one bin: no amplitude, a reason instead
    belt = lines["belt_revolution"]
    assert belt["apparent"] < out["resolution"]
    assert belt["resolvable"] is False and belt["amplitude"] is None
    assert "below one bin" in belt["reason"]
    # two lines less than a bin apart (here the rotor and the folded belt_mode_2) cannot
    # be told apart: neither gets the other's amplitude
    close = [n for n, ln in lines.items() if "less than one bin" in ln.get("reason", "")]
    for name in close:
        other = lines[name]["reason"].split("from ")[1].split(":")[0]
        assert abs(lines[other]["apparent"] - lines[name]["apparent"]) < out["resolution"]
        assert lines[name]["amplitude"] is None
    shaft = lines["stage2_shaft"]
    assert shaft["resolvable"] is True and shaft["amplitude"] > 0.0
    # a profile without the tension says so
    code = main(["spectrum", str(rec), "--profile", str(REFERENCE_PROFILE), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert "belt.tension_n" in out["notes"][0]


def test_a_structural_mode_is_monitored_where_resolvable(tmp_path: Path) -> None:
    out = generate(WHITE, tmp_path / "w", days=1, per_day=1, seed=3)
    cal_files = sorted((out.folder / "calibration").glob("*.csv"))
    cal = calibrate([load_recording(f, profile=WHITE).recording for f in cal_files], WHITE)
    run = run_virtual(WHITE, payload_kg=20.0, seed=4)
    plain = recording_features(inspect_recording(run.recording, WHITE), cal)
    modes = {k: v for k, v in plain.values.items() if k.startswith("mode_")}
    # the first belt mode (72 Hz at 6 ms) stands clear; the two-mass mode lies in a
    # shaft comb and the second belt mode folds onto one: unresolvable, no number
    assert set(modes) == {"mode_belt_mode_1", "mode_belt_mode_2", "mode_two_mass_mode"}
    assert math.isfinite(modes["mode_belt_mode_1"]) and modes["mode_belt_mode_1"] < 0.01
    assert math.isnan(modes["mode_two_mass_mode"]) and math.isnan(modes["mode_belt_mode_2"])
    # a resonance of 0.05 Nm at the mode: read at its amplitude
    (line,) = [
        ln
        for ln in characteristic_lines(  # as identification reads the profile (no model:)
            cal.id_profile, plain.spectrum.speed_rpm, payload_kg=plain.values["payload_kg"]
        )
        if ln.name == "belt_mode_1"
    ]
    rec = run.recording
    ringing = rec.torque + 0.05 * np.sin(2.0 * np.pi * line.frequency_hz * rec.time)
    rung = dataclasses.replace(rec, channels={**rec.channels, "torque": ringing})
    feats = recording_features(inspect_recording(rung, WHITE), cal)
    assert feats.values["mode_belt_mode_1"] == pytest.approx(0.05, rel=0.2)
    assert feature_spec("mode_belt_mode_1").cause == "structure"
