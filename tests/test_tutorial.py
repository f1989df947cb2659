"""The tutorial "Your own conveyor" runs as written (docs/tutorial/your-own-conveyor.md).

The files and commands come from the page's code blocks, so page and test
cannot drift: a ``yaml title="PATH"`` block is written to PATH, each line of
a ``sh`` block is run in order in an empty folder; ``chaintwin serve`` is
started on a free port and asked over HTTP. Beside running, the test checks
what the page promises against the virtual conveyor's truth: the calibrated
rail friction near the profile's ``model.friction``, the weighed payload
within three standard uncertainties of the simulated one, the friction
alarm named ``friction``, and the served conveyor with that alarm.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest
import yaml

PAGE = Path(__file__).resolve().parents[1] / "docs" / "tutorial" / "your-own-conveyor.md"
BLOCK = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```", re.M | re.S)

pytestmark = pytest.mark.slow


def page_blocks() -> list[tuple[str, str, str]]:
    """The page's code blocks in order: (language, attributes, content)."""
    return [(m[1], m[2], m[3]) for m in BLOCK.finditer(PAGE.read_text(encoding="utf-8"))]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _get(url: str, token: str) -> Any:
    request = urllib.request.Request(url, headers={"Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(request, timeout=10) as response:
        return json.loads(response.read())


def _serve(argv: list[str], cwd: Path, env: dict[str, str], token: str) -> Any:
    """Run ``chaintwin serve`` on a free port until it answers; the conveyors it lists."""
    port = _free_port()
    log = cwd / "serve.log"
    with (
        log.open("w", encoding="utf-8") as err,
        subprocess.Popen(
            [*argv, "--port", str(port)], cwd=cwd, env=env, stdout=err, stderr=err
        ) as server,
    ):
        try:
            url = f"http://127.0.0.1:{port}/api/v1/conveyors"
            deadline = time.monotonic() + 120.0  # a bound on waiting, not a timing assert
            while True:
                if server.poll() is not None:
                    pytest.fail(f"chaintwin serve ended: {log.read_text(encoding='utf-8')}")
                try:
                    return _get(url, token)
                except (urllib.error.URLError, ConnectionError):
                    if time.monotonic() > deadline:
                        pytest.fail("chaintwin serve did not answer")
                    time.sleep(0.2)
        finally:
            server.terminate()
            server.wait(timeout=30)


def test_the_page_has_the_steps_it_promises() -> None:
    blocks = page_blocks()
    commands = [line for lang, _, text in blocks if lang == "sh" for line in text.splitlines()]
    for step in ("simulate", "calibrate", "weigh", "generate", "monitor", "ingest", "serve"):
        assert any(line.startswith(f"chaintwin {step} ") for line in commands), step
    assert any(lang == "yaml" and 'title="profiles/' in attrs for lang, attrs, _ in blocks)


def test_the_tutorial_runs_as_written(tmp_path: Path) -> None:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    outputs: dict[str, str] = {}
    token = ""
    served: Any = None
    profile: dict[str, Any] = {}
    for lang, attrs, text in page_blocks():
        title = re.search(r'title="([^"]+)"', attrs)
        if lang == "yaml" and title:
            path = tmp_path / title.group(1)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
            profile = yaml.safe_load(text)
            continue
        if lang != "sh":
            continue
        for line in text.splitlines():
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            argv = shlex.split(line)
            assert argv[0] == "chaintwin", line
            if argv[1] == "serve":
                served = _serve(argv, tmp_path, env, token)
                continue
            # the shell's glob, as the reader's shell expands it
            run = subprocess.run(
                ["bash", "-c", line], cwd=tmp_path, env=env, capture_output=True, text=True
            )
            assert run.returncode == 0, f"{line}\n{run.stdout}\n{run.stderr}"
            outputs[line] = run.stdout
            if argv[1:3] == ["token", "create"]:
                found = re.search(r"ct_[A-Za-z0-9_-]+", run.stdout)
                assert found, run.stdout
                token = found.group()

    calibration = json.loads((tmp_path / "pallet-line-07.calibration.json").read_text())
    parameters = calibration["parameters"]
    fitted = dict(zip(parameters["names"], parameters["values"], strict=True))
    assert fitted["mu"] == pytest.approx(profile["model"]["friction"], rel=0.05)

    (weighed,) = json.loads(next(v for k, v in outputs.items() if "weigh " in k))
    simulated = float(re.search(r"--payload (\S+) --seed 10", PAGE.read_text())[1])  # type: ignore[index]
    assert abs(weighed["payload_kg"] - simulated) <= 3.0 * weighed["uncertainty_kg"]

    monitored = json.loads(next(v for k, v in outputs.items() if k.startswith("chaintwin monitor")))
    (conveyor,) = monitored["conveyors"]
    assert [a["cause"] for a in conveyor["open_alarms"]] == ["friction"]

    assert served is not None
    listed = served if isinstance(served, list) else served.get("conveyors", served)
    assert "pallet-line-07" in json.dumps(listed)
