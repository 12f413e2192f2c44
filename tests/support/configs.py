"""Configuration writers of the tests."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["gateway_config_json", "write_gateway_toml"]


def write_gateway_toml(
    path: Path,
    vehicle: str,
    bus: dict,
    devices: dict[str, dict],
    status_period_s: float = 0.2,
) -> Path:
    """A gateway TOML (written with json-compatible inline values)."""
    lines = [
        f"vehicle = {json.dumps(vehicle)}",
        f"status_period_s = {status_period_s}",
        "",
        "[bus]",
    ]
    lines += [f"{k} = {json.dumps(v)}" for k, v in bus.items()]
    for name, dev in devices.items():
        lines += ["", f"[devices.{name}]"]
        for k, v in dev.items():
            if isinstance(v, dict):
                inner = ", ".join(f"{ik} = {json.dumps(iv)}" for ik, iv in v.items())
                lines.append(f"{k} = {{ {inner} }}")
            else:
                lines.append(f"{k} = {json.dumps(v)}")
    path.write_text("\n".join(lines) + "\n")
    return path


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def gateway_config_json(vehicle: str, url: str) -> str:
    """The JSON configuration (``GatewayConfig.model_dump_json``) of a gateway with one PD0 DVL on
    the serial port ``url``."""
    from auvgw.config.gateway import parse_gateway_config

    dvl = {"format": "pd0", "transport": {"kind": "serial", "url": url}}
    cfg = parse_gateway_config({"vehicle": vehicle, "devices": {"dvl": dvl}})
    return cfg.model_dump_json()
