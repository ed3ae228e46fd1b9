"""Ed25519 signing keys of check records and the keys an endpoint trusts, kept under
``$XDG_CONFIG_HOME/funrec-robot/`` (default ``~/.config/funrec-robot/``).

On first use a user gets a signing key (``signing_key.pem``, mode 0600) whose public half is trusted at
once, so one user on one machine can ``check`` and ``send`` with no setup. Other keys are trusted by adding
their public key to ``trusted_keys.txt`` (``funrec-robot keys --trust HEX``).
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from funrec.errors import FunrecError

SIGNING_KEY_FILE = "signing_key.pem"
"""PKCS#8 PEM of the user's Ed25519 signing key (mode 0600)."""
TRUSTED_KEYS_FILE = "trusted_keys.txt"
"""One trusted public key a line: 64 hex digits, then an optional label."""


class TrustError(FunrecError):
    """A signature, key or credential is missing, forged or not trusted; the message says which."""


def config_dir() -> Path:
    """``$XDG_CONFIG_HOME/funrec-robot`` (``~/.config/funrec-robot`` without it)."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "funrec-robot"


def write_private(path: Path, data: bytes) -> None:
    """Write a secret file readable by its owner only (created with mode 0600, never world-readable)."""
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)
    os.chmod(path, 0o600)


def read_private(path: Path) -> bytes:
    """A secret file's bytes; refuses one that others may read (as ssh does).

    Raises:
        TrustError: group or others may read or write it.
    """
    mode = path.stat().st_mode & 0o077
    if mode:
        raise TrustError(f"{path}: mode {oct(path.stat().st_mode & 0o777)} lets others read it; run chmod 600 {path}")
    return path.read_bytes()


@dataclass(frozen=True)
class SigningKey:
    """An Ed25519 private key and its public key as 64 hex digits."""

    private: Any
    """cryptography's Ed25519PrivateKey."""
    public_hex: str

    def sign(self, payload: bytes) -> str:
        return self.private.sign(payload).hex()


def _public_hex(private: Any) -> str:
    from cryptography.hazmat.primitives import serialization

    raw = private.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return raw.hex()


def load_signing_key(directory: Path | None = None, create: bool = True) -> SigningKey:
    """The user's signing key; created (and its public key trusted) on first use.

    Raises:
        TrustError: no key and ``create`` is False, or a key file others may read.
    """
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    directory = config_dir() if directory is None else directory
    path = directory / SIGNING_KEY_FILE
    if path.is_file():
        private = serialization.load_pem_private_key(read_private(path), password=None)
        if not isinstance(private, Ed25519PrivateKey):
            raise TrustError(f"{path}: not an Ed25519 key")
        return SigningKey(private, _public_hex(private))
    if not create:
        raise TrustError(f"{path}: no signing key; `funrec-robot check` creates one")
    private = Ed25519PrivateKey.generate()
    pem = private.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    write_private(path, pem)
    key = SigningKey(private, _public_hex(private))
    trust_key(key.public_hex, "own key (created on first use)", directory)
    return key


def fingerprint(public_hex: str) -> str:
    """Short name of a public key: the first 16 hex digits of its sha256."""
    return hashlib.sha256(bytes.fromhex(public_hex)).hexdigest()[:16]


def _check_public_hex(text: str) -> str:
    text = text.strip().lower()
    if len(text) != 64 or any(c not in "0123456789abcdef" for c in text):
        raise TrustError(f"public key {text[:80]!r}: expected 64 hex digits (an Ed25519 public key)")
    return text


def trusted_keys(directory: Path | None = None) -> dict[str, str]:
    """Trusted public keys (hex) -> label. Missing file: none."""
    path = (config_dir() if directory is None else directory) / TRUSTED_KEYS_FILE
    keys: dict[str, str] = {}
    if not path.is_file():
        return keys
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        key, _, label = line.strip().partition(" ")
        try:
            keys[_check_public_hex(key)] = label.strip()
        except TrustError as exc:
            raise TrustError(f"{path} line {n}: {exc}") from None
    return keys


def trust_key(public_hex: str, label: str = "", directory: Path | None = None) -> Path:
    """Add a public key (64 hex digits, or a ``funrec-robot keys --export`` line) to the trusted keys (no-op
    if already there).

    Raises:
        TrustError: not an Ed25519 public key in hex.
    """
    directory = config_dir() if directory is None else directory
    public_hex = _check_public_hex((public_hex.split() or [""])[0])  # also a whole `keys --export` line
    path = directory / TRUSTED_KEYS_FILE
    if public_hex not in trusted_keys(directory):
        directory.mkdir(parents=True, exist_ok=True, mode=0o700)
        with open(path, "a") as handle:
            handle.write(f"{public_hex} {' '.join(label.split())}\n")
    return path


def canonical_json(data: Any) -> bytes:
    """The bytes that are signed: sorted keys, no spaces, ASCII, finite numbers only."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode()


def sign(data: dict[str, Any], key: SigningKey) -> dict[str, Any]:
    """A signature block over ``data``'s canonical JSON."""
    return {"algorithm": "ed25519", "public_key": key.public_hex, "value": key.sign(canonical_json(data))}


def verify(data: Any, signature: Any, trusted: dict[str, str], what: str) -> str:
    """Check a signature block over ``data``; returns the signer's label.

    Raises:
        TrustError: no or malformed signature, an untrusted key or a signature that does not match ``data``.
    """
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    if not isinstance(signature, dict) or signature.get("algorithm") != "ed25519":
        raise TrustError(f"{what}: not signed (no ed25519 signature); run `funrec-robot check` to make a signed record")
    public_hex, value = signature.get("public_key"), signature.get("value")
    if not isinstance(public_hex, str) or not isinstance(value, str):
        raise TrustError(f"{what}: malformed signature block")
    try:
        public_hex = _check_public_hex(public_hex)
        raw_signature = bytes.fromhex(value)
    except (TrustError, ValueError):
        raise TrustError(f"{what}: malformed signature block") from None
    if public_hex not in trusted:
        raise TrustError(
            f"{what}: signed by untrusted key {fingerprint(public_hex)}; trust it with "
            f"`funrec-robot keys --trust {public_hex}` if you know whose it is"
        )
    try:
        Ed25519PublicKey.from_public_bytes(bytes.fromhex(public_hex)).verify(raw_signature, canonical_json(data))
    except (InvalidSignature, ValueError):
        raise TrustError(f"{what}: signature does not match its contents (forged or edited)") from None
    return trusted[public_hex] or fingerprint(public_hex)


def export_public(key: SigningKey) -> str:
    """A line another machine can pass to ``funrec-robot keys --trust``."""
    return f"{key.public_hex}  # funrec-robot signing key {fingerprint(key.public_hex)}"


def random_token() -> str:
    """A new secret bearer token (32 random bytes, urlsafe base64)."""
    return base64.urlsafe_b64encode(os.urandom(32)).decode().rstrip("=")


__all__ = [
    "SigningKey",
    "TrustError",
    "canonical_json",
    "config_dir",
    "export_public",
    "fingerprint",
    "load_signing_key",
    "random_token",
    "read_private",
    "sign",
    "trust_key",
    "trusted_keys",
    "verify",
    "write_private",
]
