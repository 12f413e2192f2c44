"""Detached Ed25519 signatures of recordings (docs/security.md, "Signed recordings").

``F.mcap`` is signed into ``F.mcap.sig``: one JSON object with the file's size and SHA-256, the
signer's name, its public key (raw 32 bytes, base64) and key id (``SHA256:`` and the first 16
hex digits of the key's hash), the time of signing (UTC) and the Ed25519 signature (base64) of
``b"auvgw-signature/1\\n"`` followed by the other fields as canonical JSON (sorted keys, no
spaces): the signature covers the file's hash, its size and who signed it.

:func:`check_signature` reads it back: ``valid`` (the file hashes as signed, the signature
verifies, and with ``trusted`` keys given the signer's key is one of them), ``invalid`` (with
the one-line reason), or ``unsigned``. Without trusted keys a valid signature proves the file
is the one its ``.sig`` describes, signed by whoever held that key: pass the vehicle's public key
(``--key``) to know it is the vehicle's.

Keys: :func:`make_signing_key` writes ``<stem>.sign.key`` (PKCS #8 PEM, mode 0600) and
``<stem>.sign.pub`` (SubjectPublicKeyInfo PEM). The bus's TLS identities
(``python -m auvgw.security``) are EC P-256 keys, so they are not reused; an Ed25519 PEM key from
anywhere else is. ``cryptography`` is imported when a signature is made or checked.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from auvgw.ground.errors import UserError

if TYPE_CHECKING:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import (
        Ed25519PrivateKey,
        Ed25519PublicKey,
    )

__all__ = [
    "SIG_FORMAT",
    "SignatureCheck",
    "check_signature",
    "file_sha256",
    "key_id",
    "load_public_key",
    "load_signing_key",
    "make_signing_key",
    "sign_file",
    "signature_path",
]

SIG_FORMAT = "auvgw-signature/1"
_FIELDS = ("format", "algorithm", "hash", "file", "size", "sha256", "signer", "public_key",
           "key_id", "signed_at")  # fmt: skip
_BLOCK = 1 << 20


def signature_path(path: str | Path) -> Path:
    """Where the detached signature of ``path`` lives: ``path`` + ``.sig``."""
    p = Path(path)
    return p.with_name(p.name + ".sig")


def file_sha256(path: str | Path) -> tuple[str, int]:
    """(hex SHA-256, size in bytes) of a file, read in 1 MiB blocks."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        while block := f.read(_BLOCK):
            h.update(block)
            size += len(block)
    return h.hexdigest(), size


def _raw_public(key: Ed25519PublicKey) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def key_id(raw_public: bytes) -> str:
    """A short name of a public key: ``SHA256:`` and 16 hex digits of its raw bytes' hash."""
    return "SHA256:" + hashlib.sha256(raw_public).hexdigest()[:16]


def _message(fields: Mapping[str, object]) -> bytes:
    body = json.dumps({k: fields[k] for k in _FIELDS}, sort_keys=True, separators=(",", ":"))
    return (SIG_FORMAT + "\n" + body).encode()


def make_signing_key(stem: str | Path, *, force: bool = False) -> tuple[Path, Path]:
    """Write a new Ed25519 key pair ``<stem>.sign.key`` (0600) and ``<stem>.sign.pub``; returns
    (private, public). An existing key is kept unless ``force`` (a :class:`UserError`)."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    stem = Path(stem)
    key, pub = Path(f"{stem}.sign.key"), Path(f"{stem}.sign.pub")
    if key.exists() and not force:
        raise UserError(f"{key}: exists; keep it (a new key needs its public half redistributed)")
    if not key.parent.is_dir():
        raise UserError(f"{key}: folder {key.parent} does not exist")
    private = Ed25519PrivateKey.generate()
    pem = private.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    fd = os.open(key, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    os.chmod(key, 0o600)
    pub.write_bytes(
        private.public_key().public_bytes(
            serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
        )
    )
    return key, pub


def _read_pem(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise UserError(f"{path}: cannot read the {what}: {exc.strerror}") from None


def load_signing_key(path: Path) -> Ed25519PrivateKey:
    """The Ed25519 private key of a PEM file; a :class:`UserError` naming the file otherwise."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    try:
        key = serialization.load_pem_private_key(_read_pem(path, "signing key"), password=None)
    except (ValueError, TypeError) as exc:
        raise UserError(f"{path}: not an unencrypted PEM private key ({exc})") from None
    if not isinstance(key, Ed25519PrivateKey):
        from cryptography.hazmat.primitives.asymmetric import ec

        kind = (
            f"an EC ({key.curve.name})"
            if isinstance(key, ec.EllipticCurvePrivateKey)
            else f"a {type(key).__name__}"
        )
        raise UserError(
            f"{path}: {kind} key, not Ed25519 (the bus's TLS keys are EC P-256): make a "
            "signing key with auvgw sign --new-key STEM"
        )
    return key


def load_public_key(path: str | Path) -> bytes:
    """The raw 32 bytes of an Ed25519 public key from a PEM file (``.sign.pub``), or of the
    public half of a PEM private key; a :class:`UserError` naming the file otherwise."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    path = Path(path)
    pem = _read_pem(path, "public key")
    if b"PRIVATE KEY" in pem:
        return _raw_public(load_signing_key(path).public_key())
    try:
        key = serialization.load_pem_public_key(pem)
    except (ValueError, TypeError) as exc:
        raise UserError(f"{path}: not a PEM public key ({exc})") from None
    if not isinstance(key, Ed25519PublicKey):
        raise UserError(f"{path}: not an Ed25519 public key")
    return _raw_public(key)


def sign_file(path: str | Path, key_path: str | Path, signer: str | None = None) -> Path:
    """Sign ``path`` with the Ed25519 key at ``key_path`` into ``path.sig`` (replaced); the
    signer's name defaults to the key file's name without ``.sign.key`` / ``.key``."""
    path, key_path = Path(path), Path(key_path)
    private = load_signing_key(key_path)
    if not path.is_file():
        raise UserError(f"{path}: no such recording")
    name = signer or key_path.name.removesuffix(".key").removesuffix(".sign")
    digest, size = file_sha256(path)
    raw = _raw_public(private.public_key())
    fields: dict[str, str | int] = {
        "format": SIG_FORMAT,
        "algorithm": "ed25519",
        "hash": "sha256",
        "file": path.name,
        "size": size,
        "sha256": digest,
        "signer": name,
        "public_key": base64.b64encode(raw).decode(),
        "key_id": key_id(raw),
        "signed_at": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }
    fields["signature"] = base64.b64encode(private.sign(_message(fields))).decode()
    out = signature_path(path)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(fields, indent=1) + "\n")
    os.replace(tmp, out)
    return out


@dataclass(frozen=True)
class SignatureCheck:
    """The outcome of :func:`check_signature`; :attr:`line` is what to print."""

    path: Path
    status: Literal["valid", "invalid", "unsigned"]
    line: str
    signer: str | None = None
    key_id: str | None = None


def _invalid(path: Path, reason: str, signer: str | None = None) -> SignatureCheck:
    return SignatureCheck(path, "invalid", f"{path}: INVALID: {reason}", signer)


def check_signature(path: str | Path, trusted: tuple[bytes, ...] = ()) -> SignatureCheck:
    """Check ``path`` against ``path.sig`` (see the module docstring); ``trusted``: raw public
    keys (:func:`load_public_key`) one of which must have signed it (none: any)."""
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    path = Path(path)
    sig_path = signature_path(path)
    if not sig_path.exists():
        return SignatureCheck(path, "unsigned", f"{path}: not signed (no {sig_path.name})")
    try:
        fields = json.loads(sig_path.read_text())
        if not isinstance(fields, dict) or fields.get("format") != SIG_FORMAT:
            raise ValueError(f"not a {SIG_FORMAT} object")
        missing = [k for k in (*_FIELDS, "signature") if k not in fields]
        if missing:
            raise ValueError(f"missing {', '.join(missing)}")
        if fields["algorithm"] != "ed25519" or fields["hash"] != "sha256":
            raise ValueError(f"unsupported {fields['algorithm']}/{fields['hash']}")
        raw = base64.b64decode(fields["public_key"], validate=True)
        signature = base64.b64decode(fields["signature"], validate=True)
        public = Ed25519PublicKey.from_public_bytes(raw)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        return _invalid(path, f"{sig_path.name} is not a readable signature ({exc})")
    signer, kid = str(fields["signer"]), key_id(raw)
    who = f"{signer} (key {kid})"
    try:
        public.verify(signature, _message(fields))
    except InvalidSignature:
        return _invalid(path, f"{sig_path.name} was altered or not made by its key {kid}", signer)
    digest, size = file_sha256(path)
    if (digest, size) != (fields["sha256"], fields["size"]):
        return _invalid(
            path,
            f"file changed after signing (signed by {who} at {fields['signed_at']}: "
            f"{fields['size']} bytes, SHA-256 {fields['sha256'][:16]}...; now {size} bytes, "
            f"{digest[:16]}...)",
            signer,
        )
    if trusted and raw not in trusted:
        return _invalid(path, f"signed by {who}, which is none of the trusted keys (--key)", signer)
    trust = "a trusted key" if trusted else "not checked against a trusted key: --key"
    return SignatureCheck(
        path,
        "valid",
        f"{path}: signed by {signer}, valid (key {kid}, {fields['signed_at']}; {trust})",
        signer,
        kid,
    )
