"""Certificates for the bus's TLS / mutual TLS (docs/security.md), made with the openssl CLI.

``python -m auvgw.security OUT_DIR [--name NAME ...] [--days N] [--host H]`` writes a small CA
(``ca.pem``, ``ca.key``) and, per name (default: every component of :data:`COMPONENTS`, the
identities the shipped access control ``config/security/router.toml`` knows), ``<name>.pem`` /
``<name>.key``: an EC P-256 certificate whose common name is the name (what Zenoh's access
control matches as ``cert_common_names``), valid for TLS server and client use, with the given
hosts (default ``localhost`` and ``127.0.0.1``) as subject alternative names. Keys are written
mode 0600. An existing CA in OUT_DIR is reused, so a new or rotated identity is one more call.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = ["COMPONENTS", "make_ca", "make_identity"]

DEFAULT_HOSTS = ("localhost", "127.0.0.1")
#: an identity: a certificate common name and a file name
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
#: one identity (certificate common name) per process on the vehicle's bus, and the shore station;
#: each has its own ``config/security/<name>-bus.toml`` and its own rules in the router's ACL
COMPONENTS = (
    "router",
    "gateway",
    "fusion",
    "slam-landmark",
    "slam-magnetic",
    "slam-bathymetric",
    "pilot",
    "ros2",
    "recorder",
    "viz",
    "shore",
)


def _openssl(*args: str) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise RuntimeError(
            "the openssl command is needed to make certificates (apt install openssl)"
        )
    r = subprocess.run([exe, *args], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"openssl {args[0]} failed: {r.stderr.strip()}")


def _key(path: Path) -> None:
    _openssl(
        "genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", str(path)
    )
    os.chmod(path, 0o600)


def make_ca(out: Path, days: int = 3650, name: str = "auvgw-ca") -> tuple[Path, Path]:
    """(certificate, key) of the CA in ``out``, made if missing."""
    out.mkdir(parents=True, exist_ok=True)
    cert, key = out / "ca.pem", out / "ca.key"
    if not (cert.is_file() and key.is_file()):
        _key(key)
        _openssl(
            "req",
            "-x509",
            "-new",
            "-key",
            str(key),
            "-out",
            str(cert),
            "-days",
            str(days),
            "-subj",
            f"/CN={name}",
            "-addext",
            "basicConstraints=critical,CA:TRUE",
            "-addext",
            "keyUsage=critical,keyCertSign,cRLSign",
        )
    return cert, key


def make_identity(
    out: Path, name: str, hosts: tuple[str, ...] = DEFAULT_HOSTS, days: int = 365
) -> tuple[Path, Path]:
    """(certificate, key) of identity ``name`` (its common name), signed by the CA in ``out``."""
    ca_cert, ca_key = make_ca(out)
    cert, key = out / f"{name}.pem", out / f"{name}.key"
    _key(key)
    sans = []
    for h in hosts:
        try:
            ipaddress.ip_address(h)
            sans.append(f"IP:{h}")
        except ValueError:
            sans.append(f"DNS:{h}")
    with tempfile.TemporaryDirectory() as tmp:
        csr, ext = Path(tmp) / "req.csr", Path(tmp) / "ext.cnf"
        ext.write_text(
            f"subjectAltName={','.join(sans)}\nbasicConstraints=CA:FALSE\n"
            "keyUsage=critical,digitalSignature,keyEncipherment\n"
            "extendedKeyUsage=serverAuth,clientAuth\n"
        )
        _openssl("req", "-new", "-key", str(key), "-out", str(csr), "-subj", f"/CN={name}")
        _openssl(
            "x509",
            "-req",
            "-in",
            str(csr),
            "-CA",
            str(ca_cert),
            "-CAkey",
            str(ca_key),
            "-CAcreateserial",
            "-out",
            str(cert),
            "-days",
            str(days),
            "-extfile",
            str(ext),
        )
    return cert, key


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m auvgw.security",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("out", type=Path, help="folder for ca.pem/ca.key and <name>.pem/<name>.key")
    p.add_argument(
        "--name",
        action="append",
        default=None,
        help=f"identity (certificate common name), repeatable; default {', '.join(COMPONENTS)}",
    )
    p.add_argument(
        "--host",
        action="append",
        default=None,
        help="DNS name or IP the identity serves on (repeatable; default localhost, 127.0.0.1)",
    )
    p.add_argument("--days", type=int, default=365, help="validity of the identities (days)")
    args = p.parse_args(argv)
    hosts = tuple(args.host or DEFAULT_HOSTS)
    names = args.name or COMPONENTS
    bad = [n for n in names if not _NAME.fullmatch(n)]
    if bad or args.days < 1:
        why = f"--name {bad[0]!r}: letters, digits, '.', '_', '-'" if bad else "--days must be >= 1"
        print(f"python -m auvgw.security: {why}", file=sys.stderr)
        return 2
    for name in names:
        try:
            cert, key = make_identity(args.out, name, hosts, args.days)
        except (RuntimeError, OSError) as exc:
            print(f"python -m auvgw.security: {name}: {exc}", file=sys.stderr)
            return 2
        print(f"{name}: {cert} {key}")
    print(f"CA: {args.out / 'ca.pem'} (keep {args.out / 'ca.key'} offline)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
