"""Signed recordings (issue 27 item 3): ``auvgw sign`` writes ``F.mcap.sig`` (Ed25519 over the
file's SHA-256, size and signer); ``auvgw verify`` and ``auvgw replay`` check it. Real MCAP
files written by the recorder, real keys, the CLI run in-process."""

from __future__ import annotations

import json

import pytest

from auvgw.bus import pack_raw_attachment
from auvgw.cli import main
from auvgw.recording import McapRecorder
from auvgw.signing import check_signature, load_public_key, make_signing_key, signature_path
from auvgw.testing import endpoint, free_port


def _recording(path, n: int = 60) -> None:
    rec = McapRecorder(path, "v1", chunk_size=600)
    rec.set_gateway_config('{"vehicle": "v1", "devices": {}}')
    for i in range(n):
        rec.add("auv/v1/raw/dvl", bytes([i % 256]) * 40, pack_raw_attachment(10**9 + i, i + 1, 0))
    rec.close()


@pytest.fixture
def signed(tmp_path, capsys):
    """(recording, private key, public key): a recording signed by ``vehicle``."""
    assert main(["sign", "--new-key", str(tmp_path / "vehicle")]) == 0
    key, pub = tmp_path / "vehicle.sign.key", tmp_path / "vehicle.sign.pub"
    assert key.stat().st_mode & 0o777 == 0o600
    path = tmp_path / "dive.mcap"
    _recording(path)
    assert main(["sign", str(path), "--key", str(key)]) == 0
    capsys.readouterr()
    return path, key, pub


def _verify(capsys, *args: str) -> tuple[int, list[str]]:
    code = main(["verify", *args])
    return code, capsys.readouterr().out.splitlines()


def test_a_signed_recording_verifies_against_its_signer(signed, capsys):
    path, _key, pub = signed
    sig = json.loads(signature_path(path).read_text())
    assert sig["signer"] == "vehicle" and sig["file"] == "dive.mcap"
    assert sig["size"] == path.stat().st_size and len(sig["sha256"]) == 64
    code, out = _verify(capsys, str(path), "--key", str(pub))
    assert code == 0
    assert out[0].startswith(f"{path}: signed by vehicle, valid (key SHA256:")
    assert out[0].endswith("a trusted key)") and out[-1].endswith(": clean")
    code, out = _verify(capsys, str(path), "--require-signature")  # no --key: its own key
    assert code == 0 and "valid" in out[0] and "not checked against a trusted key" in out[0]


def test_one_flipped_byte_fails_verify_with_one_line(signed, capsys):
    path, _key, pub = signed
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    code, out = _verify(capsys, str(path), "--key", str(pub))
    assert code == 1
    invalid = [ln for ln in out if "INVALID" in ln]
    assert len(invalid) == 1, out
    assert invalid[0].startswith(f"{path}: INVALID: file changed after signing (signed by vehicle")
    # the replay refuses it, one line, before it opens the bus
    assert main(["replay", str(path), "--speed", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "INVALID: file changed after signing" in err
    assert "not replayed" in err


def test_a_signature_by_another_key_fails(signed, tmp_path, capsys):
    path, _key, _pub = signed
    other_key, other_pub = make_signing_key(tmp_path / "intruder")
    code, out = _verify(capsys, str(path), "--key", str(other_pub))
    assert code == 1
    assert [ln for ln in out if "INVALID" in ln] == [
        ln for ln in out if "which is none of the trusted keys (--key)" in ln
    ]
    # re-signed by the other key, it verifies as that signer only, and not against the vehicle
    assert main(["sign", str(path), "--key", str(other_key)]) == 0
    assert check_signature(path).signer == "intruder"
    assert check_signature(path, (load_public_key(_pub),)).status == "invalid"
    # a signature file edited to claim another signer no longer matches its signature
    sig = json.loads(signature_path(path).read_text())
    sig["signer"] = "vehicle"
    signature_path(path).write_text(json.dumps(sig))
    check = check_signature(path)
    assert check.status == "invalid" and "dive.mcap.sig was altered" in check.line


def test_unsigned_and_unusable_inputs(tmp_path, capsys):
    path = tmp_path / "plain.mcap"
    _recording(path)
    code, out = _verify(capsys, str(path))
    assert code == 0 and out[0] == f"{path}: not signed (no plain.mcap.sig)"
    code, out = _verify(capsys, str(path), "--require-signature")
    assert code == 1 and out[0].endswith("; --require-signature")
    # an EC key (what the bus's TLS identities are) cannot sign: one line naming the file
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    ec_key = tmp_path / "tls.key"
    ec_key.write_bytes(
        ec.generate_private_key(ec.SECP256R1()).private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )
    assert main(["sign", str(path), "--key", str(ec_key)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{ec_key}: an EC (secp256r1) key, not Ed25519" in err
    # the recorder checks its key before it records anything
    out_file = tmp_path / "never.mcap"
    args = ["record", "--out", str(out_file), "--sign-key", str(tmp_path / "missing.key")]
    assert main([*args, "--listen", endpoint(free_port())]) == 2
    assert "missing.key: cannot read the signing key" in capsys.readouterr().err
    assert not out_file.exists()
    assert main(["sign", "--new-key", str(tmp_path / "k")]) == 0
    assert main(["sign", "--new-key", str(tmp_path / "k")]) == 2  # an existing key is kept
    assert "k.sign.key: exists" in capsys.readouterr().err
