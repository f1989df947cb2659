"""Hostile HTTP against ``chaintwin serve`` run as a process of its own.

Each case sends what an attacker (or a broken client) would, over a raw
socket where the ordinary clients would not, and checks the exact answer,
that nothing was written, that the server's peak resident size
(``VmHWM``) stayed below its start plus the upload limit plus 100 MB, and
that a good file is still stored afterwards.
"""

from __future__ import annotations

import http.client
import json
import os
import re
import resource
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from conftest import REFERENCE_PROFILE

from chaintwin.read.profile import load_profile
from chaintwin.read.writer import write_recording
from chaintwin.simulate.virtual import run_virtual
from chaintwin.store.engine import hide_password, safe_url
from chaintwin.store.store import Store
from chaintwin.testing.postgres import free_port
from chaintwin.web.access import create_token

PROFILE = load_profile(REFERENCE_PROFILE)
UPLOAD_MB = 1
"""The served upload limit, MB (small: the refusals come quickly)."""
MEMORY_SLACK_KB = 100 * 1024
"""What the server's peak resident size may grow beyond its start and the upload limit, kB."""
GB = 1 << 30
CHUNK = 1 << 20


def _status_kb(pid: int, field: str) -> int:
    text = Path(f"/proc/{pid}/status").read_text()
    found = re.search(rf"^{field}:\s+(\d+) kB", text, re.MULTILINE)
    assert found is not None, field
    return int(found.group(1))


class Server:
    """``chaintwin serve`` in a process of its own, with its temporary folder and log."""

    def __init__(
        self,
        url: str,
        folder: Path,
        *extra: str,
        files_limit: int | None = None,
    ) -> None:
        self.url = url
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.tmp = folder / "server-tmp"
        self.tmp.mkdir()
        self.log = folder / "server.log"
        profiles = folder / "profiles"
        profiles.mkdir()
        shutil.copy(REFERENCE_PROFILE, profiles)
        # uvicorn's default proxy list, from the environment, trusts nobody here: the
        # proxy headers the tests send count only through --forwarded-allow-ips
        env = dict(
            os.environ, TMPDIR=str(self.tmp), PYTHONMALLOC="malloc", FORWARDED_ALLOW_IPS="192.0.2.1"
        )

        def limit_files() -> None:  # in the child, before it runs
            if files_limit is not None:
                resource.setrlimit(resource.RLIMIT_NOFILE, (files_limit, files_limit))

        command = [sys.executable, "-m", "chaintwin", "serve", "--db", url, "--port"]
        command += [str(self.port), "--max-upload-mb", str(UPLOAD_MB), "--profiles"]
        command += [str(profiles), *extra]
        with self.log.open("wb") as log:
            self.process = subprocess.Popen(
                command, env=env, stdout=log, stderr=subprocess.STDOUT, preexec_fn=limit_files
            )
        deadline = time.monotonic() + 120
        while True:
            assert self.process.poll() is None, self.log.read_text()
            try:
                if httpx.get(self.base + "/api/v1/health", timeout=5).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "the server did not start"
            time.sleep(0.1)
        self.start_kb = _status_kb(self.process.pid, "VmRSS")

    def peak_bounded(self) -> None:
        """The peak resident size stayed below start + upload limit + 100 MB."""
        peak = _status_kb(self.process.pid, "VmHWM")
        bound = self.start_kb + UPLOAD_MB * 1024 + MEMORY_SLACK_KB
        assert peak < bound, f"peak {peak} kB, start {self.start_kb} kB"

    def written(self) -> list[str]:
        """Files in the server's temporary folder, and files it holds open there.

        (Folders are left out: the live service makes its spool folder at start.)
        """
        names = [str(p) for p in self.tmp.rglob("*") if not p.is_dir()]
        for fd in Path(f"/proc/{self.process.pid}/fd").iterdir():
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith(str(self.tmp)):
                names.append(target)
        return names

    def stop(self) -> str:
        self.process.send_signal(signal.SIGTERM)
        try:
            self.process.wait(30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(10)
        return self.log.read_text()


SECRET = "qu3ry-s3cret"
"""The store's password, given as a query parameter of its URL (the throwaway
PostgreSQL server trusts local connections: any password opens it)."""

FILES = 256 + 64
"""The served process's limit on open files (low: its connection bound is reached quickly)."""


@pytest.fixture(scope="module")
def door(
    postgres: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[Server, dict[str, str]]]:
    """One server for the module: a PostgreSQL store, its password in the URL, few files."""
    import psycopg

    folder = tmp_path_factory.mktemp("door")
    name = f"door{os.getpid()}"
    with psycopg.connect(postgres, autocommit=True) as c:
        c.execute(f"CREATE DATABASE {name}")
    url = postgres.rsplit("/", 1)[0] + f"/{name}?password={SECRET}"
    store = Store(url)
    tokens = {r: create_token(store, f"{r}-1", r) for r in ("viewer", "maintainer", "admin")}
    store.close()
    server = Server(url, folder, "--forwarded-allow-ips", "127.0.0.1", files_limit=FILES)
    yield server, tokens
    log = server.stop()
    # nothing of the password in the log, however the server was treated
    assert SECRET not in log
    assert "Too many open files" not in log


# ------------------------------------------------------------------ raw requests
class Sent:
    """A request sent from a thread while its answer is read: the answer and bytes sent."""

    def __init__(self, port: int, head: bytes, body: Iterator[bytes]) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=60)
        self.sent = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._pump, args=(head, body), daemon=True)
        self.thread.start()
        response = http.client.HTTPResponse(self.sock)
        response.begin()
        self.status = response.status
        self.headers = dict(response.getheaders())
        self.body = response.read()
        self.stop.set()
        self.sock.shutdown(socket.SHUT_RDWR)
        self.thread.join(60)
        self.sock.close()

    def _pump(self, head: bytes, body: Iterator[bytes]) -> None:
        try:
            self.sock.sendall(head)
            for chunk in body:
                if self.stop.is_set():
                    return
                self.sock.sendall(chunk)
                self.sent += len(chunk)
        except OSError:  # the server closed, or we did once answered
            return

    def json(self) -> Any:
        return json.loads(self.body)


def _zeros(total: int) -> Iterator[bytes]:
    block = b"0" * CHUNK
    for _ in range(total // CHUNK):
        yield block


def _chunked(parts: Iterator[bytes]) -> Iterator[bytes]:
    for part in parts:
        yield b"%x\r\n" % len(part) + part + b"\r\n"
    yield b"0\r\n\r\n"


def _head(method: str, path: str, *headers: str) -> bytes:
    lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1", *headers, "", ""]
    return "\r\n".join(lines).encode()


BOUNDARY = "hostileboundary"


def _multipart_file(name: str, content: Iterator[bytes]) -> Iterator[bytes]:
    yield (
        f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="files"; filename="{name}"\r\n'
        "Content-Type: text/csv\r\n\r\n"
    ).encode()
    yield from content
    yield f"\r\n--{BOUNDARY}--\r\n".encode()


def _good_upload(server: Server, token: str, tmp: Path, seed: int) -> dict[str, Any]:
    recording = run_virtual(PROFILE, payload_kg=30.0, seed=seed).recording
    path = write_recording(recording, tmp / f"good-{seed}.csv")
    with path.open("rb") as f:
        answer = httpx.post(
            server.base + "/api/v1/recordings",
            files={"files": (path.name, f, "text/csv")},
            headers={"Authorization": f"Bearer {token}"},
            timeout=120,
        )
    assert answer.status_code == 200, answer.text
    body: dict[str, Any] = answer.json()
    return body


# ------------------------------------------------------------------ bodies
def test_an_unauthenticated_gigabyte_json_body_is_refused_before_it_is_read(
    door: tuple[Server, dict[str, str]], tmp_path: Path
) -> None:
    server, tokens = door
    for framing in (f"Content-Length: {GB}", "Transfer-Encoding: chunked"):
        body = _zeros(GB) if "Length" in framing else _chunked(_zeros(GB))
        head = _head(
            "POST", "/api/v1/alarms/X/acknowledge", "Content-Type: application/json", framing
        )
        sent = Sent(server.port, head, body)
        assert sent.status == 401, sent.body
        assert sent.json()["error"]["code"] == "unauthorized"
        assert sent.sent < GB // 4, "answered only after the body was sent"
        server.peak_bounded()
    assert server.written() == []
    stored = _good_upload(server, tokens["maintainer"], tmp_path, seed=1)
    assert stored["files"][0]["status"] == "stored"


def test_an_unauthenticated_chunked_upload_writes_nothing(
    door: tuple[Server, dict[str, str]],
) -> None:
    server, _tokens = door
    head = _head(
        "POST",
        "/api/v1/recordings",
        f"Content-Type: multipart/form-data; boundary={BOUNDARY}",
        "Transfer-Encoding: chunked",
    )
    seen: list[str] = []
    done = threading.Event()

    def watch() -> None:  # the server's temporary folder and open files while it streams
        while not done.is_set():
            seen.extend(server.written())
            done.wait(0.05)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    sent = Sent(server.port, head, _chunked(_multipart_file("big.csv", _zeros(2 * GB))))
    done.set()
    watcher.join(10)
    assert sent.status == 401 and sent.json()["error"]["code"] == "unauthorized"
    assert sent.sent < GB // 4
    assert seen == [] and server.written() == []
    # a page's upload form likewise: to the login, nothing read
    page = Sent(
        server.port,
        _head("POST", "/upload", f"Content-Type: multipart/form-data; boundary={BOUNDARY}",
              "Transfer-Encoding: chunked"),
        _chunked(_multipart_file("big.csv", _zeros(2 * GB))),
    )  # fmt: skip
    assert page.status == 303 and page.headers["location"] == "/login"
    assert server.written() == []
    server.peak_bounded()


def test_an_oversize_upload_is_refused_once_past_the_limit_with_or_without_length(
    door: tuple[Server, dict[str, str]], tmp_path: Path
) -> None:
    server, tokens = door
    auth = f"Authorization: Bearer {tokens['maintainer']}"
    kind = f"Content-Type: multipart/form-data; boundary={BOUNDARY}"
    chunked = Sent(
        server.port,
        _head("POST", "/api/v1/recordings", auth, kind, "Transfer-Encoding: chunked"),
        _chunked(_multipart_file("big.csv", _zeros(2 * GB))),
    )
    assert chunked.status == 413, chunked.body
    error = chunked.json()["error"]
    assert error == {
        "code": "too_large",
        "message": f"the upload is larger than {UPLOAD_MB} MB; send fewer files at once",
    }
    # refused once past the limit (and what the sockets' buffers hold), not at the end
    assert chunked.sent < 64 * CHUNK
    declared = Sent(
        server.port,
        _head("POST", "/api/v1/recordings", auth, kind, f"Content-Length: {2 * GB}"),
        _multipart_file("big.csv", _zeros(2 * GB)),
    )
    assert declared.status == 413 and declared.sent < 64 * CHUNK
    # a form without an upload: 64 kB at most, its token in the body or not
    login = Sent(
        server.port,
        _head("POST", "/login", "Content-Type: application/x-www-form-urlencoded",
              "Transfer-Encoding: chunked", "X-Forwarded-For: 10.0.0.99"),
        _chunked(_zeros(GB)),
    )  # fmt: skip
    assert login.status == 413 and login.sent < 64 * CHUNK
    assert "larger than 64 kB" in login.body.decode()
    server.peak_bounded()
    deadline = time.monotonic() + 10  # the refused upload's spooled file is closed
    while server.written() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.written() == []
    stored = _good_upload(server, tokens["maintainer"], tmp_path, seed=2)
    assert stored["files"][0]["status"] == "stored"


def test_an_upload_with_other_parts_is_refused_and_a_refused_file_has_a_null_id(
    door: tuple[Server, dict[str, str]], tmp_path: Path
) -> None:
    server, tokens = door
    maintainer = {"Authorization": f"Bearer {tokens['maintainer']}"}
    url = server.base + "/api/v1/recordings"
    good = write_recording(
        run_virtual(PROFILE, payload_kg=20.0, seed=7).recording, tmp_path / "a.csv"
    )
    extra = httpx.post(
        url,
        files={"files": ("a.csv", good.read_bytes(), "text/csv")},
        data={"note": "hello"},
        headers=maintainer,
        timeout=60,
    )
    assert extra.status_code == 422, extra.text
    assert extra.json()["error"] == {
        "code": "invalid",
        "message": "body.note: Extra inputs are not permitted",
    }
    text_part = httpx.post(
        url,
        content=(
            f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="files"\r\n\r\nhello\r\n'
            f"--{BOUNDARY}--\r\n"
        ).encode(),
        headers=maintainer | {"Content-Type": f"multipart/form-data; boundary={BOUNDARY}"},
        timeout=60,
    )
    assert text_part.status_code == 422, text_part.text
    assert text_part.json()["error"]["code"] == "invalid"
    # nothing of the refused requests was stored: the good file is new afterwards
    refused = httpx.post(
        url, files={"files": ("junk.csv", b"not,a\nscope\n", "text/csv")}, headers=maintainer,
        timeout=60,
    )  # fmt: skip
    assert refused.status_code == 200
    (entry,) = refused.json()["files"]
    assert entry["status"] == "refused" and entry["recording_id"] is None and entry["reason"]
    assert set(entry) == {"file", "status", "reason", "recording_id"}
    with good.open("rb") as f:
        fresh = httpx.post(url, files={"files": ("a.csv", f, "text/csv")}, headers=maintainer,
                           timeout=60)  # fmt: skip
    (stored,) = fresh.json()["files"]
    assert stored["status"] == "stored" and len(stored["recording_id"]) == 64
    assert stored["reason"] is None


# ------------------------------------------------------------------ sessions, logins
def _login(server: Server, token: str, client_ip: str, proto: str = "http") -> httpx.Response:
    return httpx.post(
        server.base + "/login",
        data={"token": token},
        headers={"X-Forwarded-For": client_ip, "X-Forwarded-Proto": proto},
        timeout=30,
    )


def test_a_cookie_is_refused_after_logout(door: tuple[Server, dict[str, str]]) -> None:
    server, tokens = door
    login = _login(server, tokens["viewer"], "10.0.0.1")
    assert login.status_code == 303
    cookie = login.cookies["chaintwin_session"]
    jar = {"chaintwin_session": cookie}
    page = httpx.get(server.base + "/", cookies=jar, timeout=30)
    assert page.status_code == 200
    found = re.search(r'<meta name="csrf-token" content="([^"]+)">', page.text)
    assert found is not None
    api = httpx.get(server.base + "/api/v1/alarms", cookies=jar, timeout=30)
    assert api.status_code == 200
    out = httpx.post(
        server.base + "/logout", data={"csrf": found.group(1)}, cookies=jar, timeout=30
    )
    assert out.status_code == 303 and out.headers["location"] == "/login"
    # the same cookie, kept by whoever copied it: refused on the server's side
    after = httpx.get(server.base + "/api/v1/alarms", cookies=jar, timeout=30)
    assert after.status_code == 401
    again = httpx.get(server.base + "/", cookies=jar, timeout=30)
    assert again.status_code == 303 and again.headers["location"] == "/login"
    # a forged cookie (another id, or the id with a wrong signature) is no better
    session_id = cookie.partition(".")[0]
    forged = httpx.get(
        server.base + "/api/v1/alarms",
        cookies={"chaintwin_session": session_id + "." + "0" * 64},
        timeout=30,
    )
    assert forged.status_code == 401


def test_the_cookie_is_secure_when_the_trusted_proxy_says_https(
    door: tuple[Server, dict[str, str]],
) -> None:
    server, tokens = door
    plain = _login(server, tokens["viewer"], "10.0.0.2")
    tls = _login(server, tokens["viewer"], "10.0.0.2", proto="https")
    assert plain.status_code == tls.status_code == 303
    assert "secure" not in plain.headers["set-cookie"].lower()
    assert "; secure" in tls.headers["set-cookie"].lower()
    assert "httponly" in tls.headers["set-cookie"].lower()


def test_login_attempts_are_limited_per_client(door: tuple[Server, dict[str, str]]) -> None:
    server, tokens = door
    answers = [_login(server, "ct_wrong", "10.0.0.3").status_code for _ in range(10)]
    assert answers == [401] * 10
    eleventh = _login(server, tokens["viewer"], "10.0.0.3")  # the right token, too late
    assert eleventh.status_code == 429
    assert 1 <= int(eleventh.headers["retry-after"]) <= 60
    assert "too many login attempts from 10.0.0.3" in eleventh.text
    # another client (as the trusted proxy says) is not held up
    assert _login(server, tokens["viewer"], "10.0.0.4").status_code == 303


# ------------------------------------------------------------------ headers, methods
def test_every_response_carries_the_security_headers(door: tuple[Server, dict[str, str]]) -> None:
    server, tokens = door
    auth = {"Authorization": f"Bearer {tokens['viewer']}"}
    for path, headers, status in (
        ("/login", {}, 200),
        ("/docs", {}, 200),
        ("/api/v1/health", {}, 200),
        ("/api/v1/conveyors", auth, 200),
        ("/api/v1/conveyors", {}, 401),
        ("/static/app/app.js", {}, 200),
        ("/nowhere", {}, 404),
    ):
        r = httpx.get(server.base + path, headers=headers, timeout=30)
        assert r.status_code == status, path
        csp = r.headers["content-security-policy"]
        assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp, path
        assert "unsafe-inline" not in csp.split("script-src")[1].split(";")[0]
        assert r.headers["x-content-type-options"] == "nosniff", path
        assert r.headers["referrer-policy"] == "same-origin", path
        if path in ("/login", "/docs"):  # no inline script the CSP would block
            assert re.search(r"<script(?![^>]*\bsrc=)[^>]*>", r.text) is None, path
            assert " on" + "submit=" not in r.text and " on" + "click=" not in r.text


def test_a_method_not_allowed_says_which_are(door: tuple[Server, dict[str, str]]) -> None:
    server, tokens = door
    auth = {"Authorization": f"Bearer {tokens['viewer']}"}
    get_ack = httpx.get(server.base + "/api/v1/alarms/X/acknowledge", headers=auth, timeout=30)
    assert get_ack.status_code == 405
    assert get_ack.headers["allow"] == "POST"
    assert get_ack.json()["error"]["code"] == "method_not_allowed"
    put_health = httpx.put(server.base + "/api/v1/health", headers=auth, timeout=30)
    assert put_health.status_code == 405
    assert put_health.headers["allow"] == "GET"


def test_anonymous_health_keeps_its_fields_without_the_url(
    door: tuple[Server, dict[str, str]],
) -> None:
    server, tokens = door
    anonymous = httpx.get(server.base + "/api/v1/health", timeout=30).json()
    known = httpx.get(
        server.base + "/api/v1/health",
        headers={"Authorization": f"Bearer {tokens['viewer']}"},
        timeout=30,
    ).json()
    assert set(anonymous) == set(known) == {"status", "version", "store", "live"}
    assert set(anonymous["store"]) == set(known["store"]) == {"url", "revision", "conveyors"}
    assert anonymous["store"]["url"] is None
    assert known["store"]["url"] == safe_url(server.url) != server.url


# ------------------------------------------------------------------ connections
def _closed_within(sock: socket.socket, seconds: float) -> bool:
    """Whether the server closes ``sock`` within ``seconds`` (reading what it sends)."""
    sock.settimeout(seconds)
    try:
        while sock.recv(4096):
            pass
    except TimeoutError:
        return False
    except OSError:
        return True
    return True


def test_idle_and_slow_connections_are_closed(door: tuple[Server, dict[str, str]]) -> None:
    from chaintwin.web.connections import HEADERS_TIMEOUT_S

    server, _tokens = door
    idle = socket.create_connection(("127.0.0.1", server.port))
    slow = socket.create_connection(("127.0.0.1", server.port))
    stop = threading.Event()

    def trickle() -> None:  # a header a byte a second: never complete
        try:
            slow.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\n")
            while not stop.wait(1.0):
                slow.sendall(b"X")
        except OSError:
            return

    thread = threading.Thread(target=trickle, daemon=True)
    thread.start()
    try:
        started = time.monotonic()
        assert _closed_within(idle, HEADERS_TIMEOUT_S + 20)
        assert _closed_within(slow, HEADERS_TIMEOUT_S + 20)
        assert time.monotonic() - started >= HEADERS_TIMEOUT_S - 1
    finally:
        stop.set()
        thread.join(5)
        idle.close()
        slow.close()
    assert httpx.get(server.base + "/api/v1/health", timeout=30).status_code == 200


def test_a_store_password_is_hidden_in_every_form() -> None:
    assert safe_url("postgresql://u:p@ss@h/db") == "postgresql://u:***@h/db"
    assert safe_url("postgresql://u:pa/ss@h:5/db?sslmode=require&password=x") == (
        "postgresql://u:***@h:5/db?sslmode=require&password=***"
    )
    assert safe_url("postgresql://h/db?PassWord=x&sslpassword=y") == (
        "postgresql://h/db?PassWord=***&sslpassword=***"
    )
    assert safe_url("postgresql://u@h/db") == "postgresql://u@h/db"
    assert safe_url("sqlite:///a@b.db") == "sqlite:///a@b.db"  # a path, no password
    url = "postgresql://u:p@ss-w0rd@h/db?password=qq-9"
    said = 'could not translate host name "ss-w0rd@h" to address; password=qq-9'
    assert (
        hide_password(said, url) == 'could not translate host name "***@h" to address; password=***'
    )


def test_an_error_naming_a_store_shows_no_part_of_its_password(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from chaintwin.cli.app import main

    # the URL parser cuts the password at its '@': the driver is asked for the host
    # "ss-w0rd@127.0.0.1", and its error names it
    url = f"postgresql://u:p@ss-w0rd@127.0.0.1:{free_port()}/x?password=qq-9"
    for command in (["db", "upgrade", "--db", url], ["export", "--db", url]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        assert "ss-w0rd" not in err and "qq-9" not in err, err
        assert "postgresql://u:***@127.0.0.1" in err and "password=***" in err, err


def test_the_startup_line_health_and_metrics_hide_the_password(
    door: tuple[Server, dict[str, str]],
) -> None:
    server, tokens = door
    startup = server.log.read_text().splitlines()
    assert any(
        line.startswith("chaintwin serve: postgresql://") and "password=***" in line
        for line in startup
    ), startup
    anonymous = httpx.get(server.base + "/api/v1/health", timeout=30).json()
    assert anonymous["store"]["url"] is None
    known = httpx.get(
        server.base + "/api/v1/health",
        headers={"Authorization": f"Bearer {tokens['admin']}"},
        timeout=30,
    )
    assert SECRET not in known.text and "password=***" in known.text
    counts = httpx.get(
        server.base + "/api/v1/store",
        headers={"Authorization": f"Bearer {tokens['admin']}"},
        timeout=30,
    )
    assert counts.status_code == 200 and SECRET not in counts.text
    metrics = httpx.get(server.base + "/metrics", timeout=30)
    assert metrics.status_code == 200 and SECRET not in metrics.text
    assert SECRET not in server.log.read_text()


def test_connections_beyond_the_bound_are_closed_at_once(
    door: tuple[Server, dict[str, str]],
) -> None:
    from chaintwin.web.connections import FILES_RESERVED, HEADERS_TIMEOUT_S

    server, _tokens = door
    bound = FILES - FILES_RESERVED
    assert f"serving at most {bound} connections at once (open-file limit {FILES})" in (
        server.log.read_text()
    )
    held: list[socket.socket] = []
    try:
        # twice the bound of idle connections: those beyond it are closed at once
        held = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(2 * bound)]
        # "at once": all within half the headers' deadline (by which the idle ones close)
        until = time.monotonic() + HEADERS_TIMEOUT_S / 2
        closed_at_once = sum(
            _closed_within(s, max(0.01, until - time.monotonic())) for s in held[bound:]
        )
        assert closed_at_once == bound
        # the rest (idle) are closed by their deadline; then the server answers again
        assert all(_closed_within(s, HEADERS_TIMEOUT_S + 20) for s in held[:bound])
        assert httpx.get(server.base + "/api/v1/health", timeout=30).status_code == 200
    finally:
        for s in held:
            s.close()
    log = server.log.read_text()
    assert log.count(f"more than {bound} connections at once") == 1
    assert "Too many open files" not in log
    server.peak_bounded()


def test_serve_refuses_a_proxy_list_it_cannot_read(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from chaintwin.cli.app import main

    db = f"sqlite:///{tmp_path / 'p.db'}"
    assert main(["serve", "--db", db, "--forwarded-allow-ips", "10.0.0.5, proxy.lan"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "--forwarded-allow-ips: 'proxy.lan' is not an address or network" in err


# ------------------------------------------------------------------ the guard alone
def _guarded(path: str, receive: Any) -> list[dict[str, Any]]:
    """What the guard sends for one POST to ``path`` whose body comes from ``receive``."""
    import asyncio

    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import JSONResponse, Response
    from starlette.routing import Route

    from chaintwin.web.guard import Guard

    async def echo(request: Request) -> Response:
        return JSONResponse({"read": len(await request.body())})

    async def refuse(
        request: Request, status: int, code: str, message: str, headers: dict[str, str]
    ) -> Response:
        return JSONResponse({"error": {"code": code, "message": message}}, status, headers)

    app = Guard(
        Starlette(routes=[Route(path, echo, methods=["POST"])]),
        principal=lambda request: None,
        upload_limit=lambda: 1024,
        refuse=refuse,
    )
    sent: list[dict[str, Any]] = []

    async def send(message: dict[str, Any]) -> None:
        sent.append(message)

    scope = {
        "type": "http", "method": "POST", "path": path, "raw_path": path.encode(),
        "query_string": b"", "headers": [], "client": ("10.1.1.1", 5), "scheme": "http",
        "server": ("127.0.0.1", 80), "http_version": "1.1", "root_path": "",
    }  # fmt: skip
    asyncio.run(app(scope, receive, send))
    return sent


def test_a_body_that_stalls_is_refused_with_408(monkeypatch: pytest.MonkeyPatch) -> None:
    import asyncio

    from chaintwin.web import guard

    monkeypatch.setattr(guard, "BODY_IDLE_S", 0.2)
    parts = [{"type": "http.request", "body": b"token=", "more_body": True}]

    async def stalling() -> dict[str, Any]:
        if parts:
            return parts.pop()
        await asyncio.Event().wait()  # nothing more, ever
        raise AssertionError

    sent = _guarded("/login", stalling)
    assert sent[0]["status"] == 408
    assert json.loads(sent[1]["body"]) == {
        "error": {"code": "timeout", "message": "the request's body sent nothing for 0.2 s"}
    }
    # a body that comes whole is read as it is
    whole = [{"type": "http.request", "body": b"token=abc", "more_body": False}]

    async def complete() -> dict[str, Any]:
        return whole.pop()

    answered = _guarded("/login", complete)
    assert answered[0]["status"] == 200 and json.loads(answered[1]["body"]) == {"read": 9}
    headers = dict(answered[0]["headers"])
    assert headers[b"x-content-type-options"] == b"nosniff"


def test_login_attempts_are_counted_in_a_sliding_window() -> None:
    from chaintwin.web.guard import LoginAttempts

    now = [1000.0]
    attempts = LoginAttempts(attempts=3, window_s=60.0, clients=2, clock=lambda: now[0])
    assert [attempts.wait_s("a") for _ in range(3)] == [None, None, None]
    now[0] += 10.0
    assert attempts.wait_s("a") == pytest.approx(50.0)  # the first attempt leaves at 1060
    assert attempts.wait_s("b") is None  # another client
    now[0] += 50.0
    assert attempts.wait_s("a") is None  # the first three have left the window
    # at most `clients` remembered: the oldest forgotten first
    attempts.wait_s("c")
    assert set(attempts._seen) == {"a", "c"}
