"""E-mail notifications over STARTTLS: a real SMTP server (aiosmtpd) with its own certificate."""

from __future__ import annotations

import datetime as dt
import ipaddress
import smtplib
import socket
import ssl
from email.message import EmailMessage
from pathlib import Path
from typing import Any

import pytest

from chaintwin.live.notify import MailSettings, send_mail


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _self_signed(tmp_path: Path) -> tuple[Path, Path]:
    """A certificate for 127.0.0.1 and localhost, signed by its own key (PEM files)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "chaintwin test smtp")])
    now = dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=1))
        .add_extension(
            x509.SubjectAlternativeName(
                [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
            ),
            critical=False,
        )
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )
    cert_path, key_path = tmp_path / "smtp.crt", tmp_path / "smtp.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )
    return cert_path, key_path


class TlsMailServer:
    """An SMTP server that takes mail and logins only after STARTTLS."""

    def __init__(self, cert: Path, key: Path) -> None:
        from aiosmtpd.controller import Controller
        from aiosmtpd.smtp import AuthResult, LoginPassword

        self.accepted: list[tuple[list[str], bool]] = []
        outer = self

        class Handler:
            async def handle_DATA(self, server: Any, session: Any, envelope: Any) -> str:
                outer.accepted.append((list(envelope.rcpt_tos), session.ssl is not None))
                return "250 OK"

        def authenticator(
            server: Any, session: Any, envelope: Any, mechanism: str, data: Any
        ) -> Any:
            good = isinstance(data, LoginPassword) and (data.login, data.password) == (
                b"twin",
                b"pw",
            )
            return AuthResult(success=good)

        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        context.load_cert_chain(cert, key)
        self.controller = Controller(
            Handler(),
            hostname="127.0.0.1",
            port=_free_port(),
            tls_context=context,
            require_starttls=True,
            authenticator=authenticator,
            auth_require_tls=True,
        )
        self.controller.start()
        self.port = int(self.controller.port)

    def close(self) -> None:
        self.controller.stop()


def _message() -> EmailMessage:
    msg = EmailMessage()
    msg["From"] = "twin@plant.example"
    msg["To"] = "ops@plant.example"
    msg["Subject"] = "[chaintwin] test"
    msg.set_content("an alarm opened")
    return msg


def test_mail_goes_over_starttls_with_the_servers_certificate_checked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cert, key = _self_signed(tmp_path)
    server = TlsMailServer(cert, key)
    to = "ops@plant.example"
    tls = MailSettings("127.0.0.1", server.port, (to,), "twin@plant.example", True, "twin", "pw")
    try:
        # the system's CAs do not know this certificate: refused before anything is sent
        monkeypatch.setenv("SSL_CERT_FILE", str(tmp_path / "no-such-ca.pem"))
        monkeypatch.setenv("SSL_CERT_DIR", str(tmp_path))
        with pytest.raises(ssl.SSLCertVerificationError):
            send_mail(tls, to, _message())
        assert server.accepted == []
        # without STARTTLS the server takes neither the login nor the mail
        plain = MailSettings("127.0.0.1", server.port, (to,), "twin@plant.example", False)
        with pytest.raises(smtplib.SMTPException):
            send_mail(plain, to, _message())
        assert server.accepted == []
        # with the server's certificate trusted (SSL_CERT_FILE, as the docs say): sent once,
        # over TLS, after the login
        monkeypatch.setenv("SSL_CERT_FILE", str(cert))
        send_mail(tls, to, _message())
        assert server.accepted == [([to], True)]
    finally:
        server.close()
