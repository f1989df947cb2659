"""The rail friction allowance: stored in the calibration, used by weigh, overridden
on the command line; the ``friction_changed`` warning when monitoring sees friction move."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.cli.app import main
from chaintwin.identify.calibration import Calibration, load_calibration
from chaintwin.read.profile import load_profile
from chaintwin.read.writer import write_recording
from chaintwin.simulate.virtual import run_virtual
from chaintwin.validate import inspect_recording
from chaintwin.weigh import LossDrift, reweigh, weigh
from chaintwin.weigh.weigh import FRICTION_CHANGED

PROFILE = load_profile(REFERENCE_PROFILE)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    """``calibrate --friction-drift 0.1`` of two empty runs and a 50 kg one."""
    folder = tmp_path_factory.mktemp("friction")
    files = []
    for k, load in enumerate([0, 0, 50]):
        run = run_virtual(PROFILE, payload_kg=load, seed=700 + k, calibration=True)
        files.append(str(write_recording(run.recording, folder / f"cal{k}.csv")))
    out = folder / "cal.json"
    args = ["--profile", str(REFERENCE_PROFILE), "--out", str(out), "--friction-drift", "0.1"]
    code = main(["calibrate", *files, *args])
    assert code == 0
    today = run_virtual(PROFILE, payload_kg=30.0, seed=710)
    return out, [str(write_recording(today.recording, folder / "today.csv"))]


def _weigh_json(
    capsys: pytest.CaptureFixture[str], cal: Path, files: list[str], *extra: str
) -> list[dict[str, object]]:
    capsys.readouterr()
    assert main(["weigh", "--calibration", str(cal), *files, "--json", *extra]) == 0
    out: list[dict[str, object]] = json.loads(capsys.readouterr().out)
    return out


def test_calibrate_stores_the_friction_drift_and_weigh_uses_it(
    calibrated: tuple[Path, list[str]], capsys: pytest.CaptureFixture[str]
) -> None:
    cal_path, files = calibrated
    content = json.loads(cal_path.read_text())
    assert content["friction_drift"] == 0.1
    assert load_calibration(cal_path).friction_drift == 0.1
    stored = _weigh_json(capsys, cal_path, files)[0]
    given = _weigh_json(capsys, cal_path, files, "--friction-drift", "0.1")[0]
    trusted = _weigh_json(capsys, cal_path, files, "--friction-drift", "0")[0]
    # the calibration's value holds when the option is absent; 0 given overrides it
    assert stored["friction_uncertainty_kg"] == given["friction_uncertainty_kg"]
    u_stored = float(stored["friction_uncertainty_kg"])  # type: ignore[arg-type]
    u_trusted = float(trusted["friction_uncertainty_kg"])  # type: ignore[arg-type]
    per_10 = float(stored["friction_10pct_kg"])  # type: ignore[arg-type]
    # by hand: a 10 % standard uncertainty of mu adds friction_10pct_kg in quadrature
    assert u_stored**2 - u_trusted**2 == pytest.approx(per_10**2, rel=1e-6)


def test_a_calibration_without_the_field_trusts_the_friction(
    calibrated: tuple[Path, list[str]], tmp_path: Path
) -> None:
    cal_path, _files = calibrated
    content = json.loads(cal_path.read_text())
    del content["friction_drift"]
    assert Calibration.from_dict(content).friction_drift == 0.0
    content["friction_drift"] = 1.5
    with pytest.raises(Exception, match=r"friction drift 1\.5"):
        Calibration.from_dict(content)


def test_the_store_keeps_the_friction_drift(
    calibrated: tuple[Path, list[str]], tmp_path: Path
) -> None:
    from chaintwin.store.store import Store

    cal = load_calibration(calibrated[0])
    with Store(f"sqlite:///{tmp_path / 'r.db'}") as store:
        store.put_calibration(cal)
        back = store.calibration(cal.profile.id)
    assert back is not None and back.friction_drift == 0.1


def test_friction_changed_carries_the_measured_change(
    calibrated: tuple[Path, list[str]],
) -> None:
    """Monitoring sees the friction 20 % up: the warning, and the change in the friction
    signature's uncertainty (twice friction_10pct_kg), weighed by inertia or not."""
    cal = dataclasses.replace(load_calibration(calibrated[0]), friction_drift=0.0)
    ins = inspect_recording(run_virtual(PROFILE, payload_kg=30.0, seed=711).recording, PROFILE)
    res = weigh(ins, cal, loss_drift=LossDrift())
    assert res.signatures is not None and res.signatures.inertia_kg is not None
    per_10 = res.friction_10pct_kg
    assert per_10 is not None and res.friction_uncertainty_kg is not None
    moved = reweigh(res, LossDrift(), friction=False, friction_change=0.2)
    codes = [w.code for w in moved.warnings]
    assert FRICTION_CHANGED in codes and "weighed_by_inertia" in codes
    assert moved.payload_kg == res.payload_inertia_kg
    assert moved.friction_uncertainty_kg is not None
    assert moved.friction_uncertainty_kg**2 - res.friction_uncertainty_kg**2 == pytest.approx(
        (2.0 * per_10) ** 2, rel=1e-6
    )
    message = next(w.message for w in moved.warnings if w.code == FRICTION_CHANGED)
    assert "+20%" in message and f"{abs(per_10):.1f} kg per 10 %" in message
    # no ramp: the friction signature's payload, its uncertainty carrying the change
    flat = dataclasses.replace(
        res, signatures=dataclasses.replace(res.signatures, inertia_kg=None, inertia_var=None)
    )
    alone = reweigh(flat, LossDrift(), friction=False, friction_change=-0.2)
    assert alone.payload_kg == pytest.approx(res.signatures.friction_kg)
    assert alone.uncertainty_kg == pytest.approx(
        math.sqrt(res.signatures.friction_var + (2.0 * per_10) ** 2)
    )
    assert FRICTION_CHANGED in [w.code for w in alone.warnings]
    # nothing measured and no ramp: no number, but said why
    unknown = reweigh(flat, LossDrift(), friction=False)
    assert unknown.payload_kg is None
    assert [w.code for w in unknown.warnings][-2:] == [FRICTION_CHANGED, "unweighable"]
    # weighed again normally, the warning goes
    again = reweigh(moved, LossDrift())
    assert FRICTION_CHANGED not in [w.code for w in again.warnings]
