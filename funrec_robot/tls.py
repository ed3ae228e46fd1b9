"""Transport credentials of ``funrec-robot/2``: the endpoint's self-signed TLS certificate, the bearer tokens
it accepts, and the client's token, all under ``$XDG_CONFIG_HOME/funrec-robot/`` and created on first use.

On one machine ``serve-sim`` and ``send`` find each other's files there: the client pins the endpoint's
certificate (``endpoint_cert.pem``) and presents ``token``, whose sha256 is in ``authorized_tokens``. For
another machine copy the certificate to the client (``send --server-cert``) and authorize the client's token
on the endpoint (``funrec-robot keys --authorize-token TOKEN``). A client certificate signed by a CA the
endpoint is given (``serve-sim --client-ca``) authenticates too.
"""

from __future__ import annotations

import datetime
import hashlib
import hmac
import ipaddress
import ssl
from pathlib import Path

from funrec_robot.keys import TrustError, config_dir, random_token, read_private, write_private

CERT_FILE = "endpoint_cert.pem"
"""The endpoint's self-signed certificate (public; clients pin it)."""
CERT_KEY_FILE = "endpoint_key.pem"
"""Its private key (mode 0600)."""
TOKEN_FILE = "token"
"""The client's bearer token (mode 0600)."""
AUTHORIZED_TOKENS_FILE = "authorized_tokens"
"""sha256 hex of each token the endpoint accepts, one a line with an optional label (mode 0600)."""


def endpoint_certificate(directory: Path | None = None) -> tuple[Path, Path]:
    """(certificate, private key) of the endpoint, created on first use (ECDSA P-256, 10 years, for
    localhost, 127.0.0.1 and ::1; clients pin the certificate itself, not a host name)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    directory = config_dir() if directory is None else directory
    cert_path, key_path = directory / CERT_FILE, directory / CERT_KEY_FILE
    if cert_path.is_file() and key_path.is_file():
        read_private(key_path)  # refuses a key others may read
        return cert_path, key_path
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "funrec-robot endpoint")])
    now = datetime.datetime.now(datetime.timezone.utc)
    names = [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1")), x509.IPAddress(ipaddress.ip_address("::1"))]
    cert = (
        x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
        .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=3650))
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )
    write_private(key_path, key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def authorize_token(token: str, label: str = "", directory: Path | None = None) -> Path:
    """Let the endpoint accept ``token`` (only its sha256 is stored)."""
    directory = config_dir() if directory is None else directory
    path = directory / AUTHORIZED_TOKENS_FILE
    lines = read_private(path).decode().splitlines() if path.is_file() else []
    digest = token_hash(token.strip())
    if not any(line.split(" ")[0] == digest for line in lines):
        lines.append(f"{digest} {' '.join(label.split())}".rstrip())
        write_private(path, ("\n".join(lines) + "\n").encode())
    return path


def client_token(directory: Path | None = None) -> str:
    """The client's token; on first use created and authorized on this machine's endpoint."""
    directory = config_dir() if directory is None else directory
    path = directory / TOKEN_FILE
    if path.is_file():
        return read_private(path).decode().strip()
    token = random_token()
    write_private(path, (token + "\n").encode())
    authorize_token(token, "this machine's user (created on first use)", directory)
    return token


def authorized_hashes(directory: Path | None = None) -> frozenset[str]:
    """sha256 hex of the accepted tokens (none without the file)."""
    path = (config_dir() if directory is None else directory) / AUTHORIZED_TOKENS_FILE
    if not path.is_file():
        return frozenset()
    return frozenset(line.split(" ")[0] for line in read_private(path).decode().splitlines() if line.strip())


def token_accepted(token: object, accepted: frozenset[str]) -> bool:
    """Constant-time membership of a presented token's hash."""
    if not isinstance(token, str) or not token:
        return False
    digest = token_hash(token)
    return any(hmac.compare_digest(digest, known) for known in accepted)


def server_context(cert: Path, key: Path, client_ca: Path | None = None) -> ssl.SSLContext:
    """TLS 1.2+ server context; with ``client_ca`` a client certificate it signed authenticates the client."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.load_cert_chain(cert, key)
    if client_ca is not None:
        context.load_verify_locations(cafile=str(client_ca))
        context.verify_mode = ssl.CERT_OPTIONAL
    return context


def client_context(server_cert: Path | None = None, client_cert: Path | None = None, client_key: Path | None = None) -> ssl.SSLContext:
    """TLS client context pinned to the endpoint's certificate (default: this machine's endpoint's).

    Raises:
        TrustError: no certificate to pin.
    """
    server_cert = (config_dir() / CERT_FILE) if server_cert is None else Path(server_cert)
    if not server_cert.is_file():
        raise TrustError(
            f"{server_cert}: no endpoint certificate to trust; on the endpoint's machine `funrec-robot serve-sim` "
            "creates it (copy it here and pass --server-cert)"
        )
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.check_hostname = False  # pinned: only this exact certificate is accepted, whatever the address
    context.verify_mode = ssl.CERT_REQUIRED
    context.load_verify_locations(cafile=str(server_cert))
    if client_cert is not None:
        context.load_cert_chain(client_cert, client_key)
    return context


__all__ = [
    "authorize_token",
    "authorized_hashes",
    "client_context",
    "client_token",
    "endpoint_certificate",
    "server_context",
    "token_accepted",
    "token_hash",
]
