"""``auvgw sign FILE.mcap --key NAME.sign.key``: sign recordings (detached Ed25519 signatures).

    auvgw sign --new-key keys/vehicle             # keys/vehicle.sign.key (0600) + .sign.pub
    auvgw sign dive42.mcap --key keys/vehicle.sign.key
    auvgw verify dive42.mcap --key keys/vehicle.sign.pub

Writes ``FILE.mcap.sig`` beside each file: its size and SHA-256, the signer (``--signer``, default
the key file's name), the public key, the time, and the Ed25519 signature over them
(docs/security.md). ``auvgw verify`` and ``auvgw replay`` check it when present. ``auvgw record
--sign-key`` signs at the end of a recording. Exit 2 on a key or file that cannot be used.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from auvgw.commands.common import SubParsers, UserError, add_command


def register(sub: SubParsers) -> None:
    p = add_command(sub, "sign", __doc__)
    p.add_argument("files", type=Path, nargs="*", metavar="FILE.mcap", help="recordings to sign")
    p.add_argument("--key", type=Path, metavar="KEY", help="Ed25519 private key (PEM)")
    p.add_argument("--signer", default=None, help="signer name (default: the key file's name)")
    p.add_argument(
        "--new-key",
        type=Path,
        default=None,
        metavar="STEM",
        help="make a signing key pair STEM.sign.key (mode 0600) and STEM.sign.pub, then exit",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from auvgw.signing import make_signing_key, sign_file

    if args.new_key is not None:
        if args.files or args.key:
            raise UserError("--new-key makes a key only: give no FILE and no --key with it")
        key, pub = make_signing_key(args.new_key)
        print(f"signing key {key} (keep it on the vehicle), public key {pub} (for auvgw verify)")
        return 0
    if not args.files or args.key is None:
        raise UserError("give the recordings to sign and --key KEY (or --new-key STEM)")
    for path in args.files:
        sig = sign_file(path, args.key, args.signer)
        print(f"{path}: signed, {sig}")
    return 0
