"""``chaintwin demo --live``: the demo's plant as drives publishing over OPC UA, followed live.

After the batch demo has built the store (history, calibrations, baselines),
each demo conveyor becomes a simulated drive (:class:`~chaintwin.live.drive_sim.DriveSim`,
an asyncua server on a port of its own) that publishes a scope every few
seconds; ``white-belt-01``, healthy in the batch, now develops a rail
friction rise within a minute. The live service (``chaintwin serve
--opcua``) follows the drives into the same store with the dashboard on,
serves the results over OPC UA (``--opcua-endpoint``, a user printed)
and sends its alarm notifications, signed, to a small webhook receiver
running beside it that checks each signature and prints what arrived.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import secrets
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from rich.console import Console

from chaintwin.cli.common import safe

__all__ = ["LIVE_FAULTS", "run_live"]

LIVE_FAULTS: dict[str, tuple[str, int, int]] = {
    "white-belt-01": ("friction:0.8", 2, 6),
    "incline-line-02": ("friction:0.5", 0, 0),
    "short-fast-03": ("rail_obstacle:1.5", 0, 0),
}
"""Per demo conveyor: its fault, onset and ramp in scopes (the batch demo's
faults carry on at their full severity; white-belt-01's is new, so that an
alarm opens, and is notified, while one watches)."""

INTERVAL_S = 3.0
"""Seconds between two scopes of one simulated drive."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def webhook_receiver(secret: bytes, console: Console) -> Iterator[str]:
    """An HTTP receiver of the service's notifications, printing each with its signature check.

    Yields its URL; stops on leaving.
    """

    class Receiver(BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            body = self.rfile.read(int(self.headers.get("Content-Length") or 0))
            given = self.headers.get("X-Chaintwin-Signature", "")
            want = "sha256=" + hmac.new(secret, body, "sha256").hexdigest()
            valid = hmac.compare_digest(given, want)
            self.send_response(204 if valid else 401)
            self.end_headers()
            try:
                doc = json.loads(body)
            except ValueError:
                doc = {}
            console.print(
                f"[bold]webhook[/]: {safe(str(doc.get('event')))} "
                f"{safe(str(doc.get('conveyor')))} {safe(str(doc.get('feature')))} (probable "
                f"cause {safe(str(doc.get('cause')))}), signature "
                f"{'valid' if valid else 'INVALID'}; {safe(str(doc.get('link')))}",
                highlight=False,
                soft_wrap=True,
            )

        def log_message(self, format: str, *args: object) -> None:
            return  # the console line above says it

    server = ThreadingHTTPServer(("127.0.0.1", _free_port()), Receiver)
    thread = threading.Thread(target=server.serve_forever, name="webhook", daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/chaintwin"
    finally:
        server.shutdown()
        server.server_close()


@contextmanager
def simulated_drives(ids: list[str], console: Console) -> Iterator[dict[str, str]]:
    """The demo conveyors as simulated drives in an event loop of their own thread.

    Yields each conveyor's endpoint; the drives stop on leaving.
    """
    from chaintwin.cli.demo_cmd import examples_dir
    from chaintwin.live.drive_sim import DriveSim
    from chaintwin.read.profile import load_profiles
    from chaintwin.simulate.faults import parse_fault

    profiles = load_profiles(examples_dir() / "profiles")
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, name="drive-sims", daemon=True)
    thread.start()
    stop = asyncio.Event()
    drives = []
    for k, cid in enumerate(ids):
        fault, onset, ramp = LIVE_FAULTS[cid]
        drives.append(
            DriveSim(
                profiles[cid],
                port=_free_port(),
                host="127.0.0.1",
                interval_s=INTERVAL_S,
                faults=[parse_fault(fault)],
                onset=onset,
                ramp=ramp,
                seed=101 + k,
            )
        )
    console.print(
        f"[bold]live[/]: starting {len(drives)} simulated drives (OPC UA servers, about 5 s each)",
        highlight=False,
    )
    tasks = [asyncio.run_coroutine_threadsafe(d.run(stop), loop) for d in drives]
    try:
        yield {d.profile.id: d.endpoint for d in drives}
    finally:
        loop.call_soon_threadsafe(stop.set)
        for t in tasks:
            try:
                t.result(timeout=30)
            except Exception as exc:  # a drive that failed to stop is reported, not fatal
                console.print(f"drive-sim did not stop cleanly: {exc}", highlight=False)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()


OPCUA_PORT = 4840
"""The OPC UA server's port in the demo (OPC UA's registered port), when free."""


def _port_or_free(port: int) -> int:
    """``port`` when it is free on 127.0.0.1, else one that is."""
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return _free_port()
    return port


def _opcua_user(out: Path) -> tuple[str, str]:
    """A new viewer token for OPC UA clients on the demo's store: (user name, password)."""
    from chaintwin.store.store import Store
    from chaintwin.web.access import create_token, list_tokens

    store = Store(f"sqlite:///{out / 'plant.db'}")
    try:
        name = f"demo-opcua-{len(list_tokens(store)) + 1}"
        return name, create_token(store, name, "viewer")
    finally:
        store.close()


def run_live(out: Path, *, port: int, console: Console) -> None:
    """Follow the demo's conveyors as live drives into the demo's store until Ctrl-C.

    ``out`` holds the batch demo's store (``plant.db``); the OPC UA
    configuration and the webhook's secret are written beside it.
    """
    from chaintwin.extras import require_extra

    require_extra("live", "asyncua", "watchfiles", "httpx", needed_by="chaintwin demo --live")
    from chaintwin.cli.demo_cmd import DEMO_PLANT, demo_token, examples_dir
    from chaintwin.cli.serve_cmd import LiveArgs, serve

    ids = [cid for cid, _fault in DEMO_PLANT]
    secret_file = out / "webhook.secret"
    secret = secrets.token_hex(16).encode()
    secret_file.write_bytes(secret + b"\n")
    db = f"sqlite:///{out / 'plant.db'}"
    token = demo_token(out)
    opcua_user, opcua_token = _opcua_user(out)
    opcua_endpoint = f"opc.tcp://127.0.0.1:{_port_or_free(OPCUA_PORT)}"
    pki = out / "opcua-pki"
    with webhook_receiver(secret, console) as hook, simulated_drives(ids, console) as endpoints:
        config = out / "drives.yaml"
        config.write_text(
            "drives:\n"
            + "".join(f"  - conveyor: {cid}\n    endpoint: {ep}\n" for cid, ep in endpoints.items())
            + "reconnect: {initial_s: 1, max_s: 5}\n"
        )
        console.print(
            f"[bold]live[/]: drives publish a scope every {INTERVAL_S:g} s "
            f"({', '.join(f'{c}: {LIVE_FAULTS[c][0]}' for c in ids)}); the service follows "
            f"them ({config}) into {db} and notifies {hook}.\nOpen http://127.0.0.1:{port}/ "
            f"and log in with this viewer token:\n{token}\n",
            highlight=False,
            soft_wrap=True,
        )
        console.print(
            f"[bold]OPC UA[/]: the results at {opcua_endpoint} (Basic256Sha256, sign and "
            f"encrypt); user [bold]{opcua_user}[/], password:\n{opcua_token}\nA client's "
            f"certificate is refused the first time and kept in {pki / 'rejected' / 'certs'}: "
            f"move it to {pki / 'trusted' / 'certs'} and connect again. Browse Objects > "
            "Conveyors (docs/opcua-server.md).\nCtrl-C stops everything.",
            highlight=False,
            soft_wrap=True,
        )
        serve(
            db,
            examples_dir() / "profiles",
            "127.0.0.1",
            port,
            20.0,
            live=LiveArgs(
                opcua=config,
                notify_urls=[hook],
                notify_secret_file=secret_file,
                public_url=f"http://127.0.0.1:{port}",
                settle_s=0.0,
                opcua_endpoint=opcua_endpoint,
                opcua_cert_dir=pki,
            ),
        )
