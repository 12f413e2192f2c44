"""Render a Rerun recording to a PNG the way ``docs/viz.md``'s screenshots are made.

Rerun's own web viewer (``rerun --serve-web``, the wasm app) loads the ``.rrd`` over HTTP from a
local file server that sends ``Access-Control-Allow-Origin: *``; headless Chromium draws it with
software WebGL (SwiftShader) and the page is captured through the DevTools protocol
(``Page.captureScreenshot``) ``--wait`` seconds after it opened. The software-rendered viewer
ingests a file at roughly real time while it follows the newest data, so a recording of W wall
seconds needs a wait of about 2.5 W (250 s for a 90 s harbour run; ``docs/viz.md``).

Needs ``chromium`` (Debian: ``apt-get install chromium``) and the project's venv (``rerun``,
``websockets``). Example::

    .venv/bin/python docs/render_rrd.py out/demo.rrd docs/viz-survey.png --wait 300
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import functools
import http.server
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _CorsHandler(http.server.SimpleHTTPRequestHandler):
    def end_headers(self) -> None:
        self.send_header("Access-Control-Allow-Origin", "*")
        super().end_headers()

    def log_message(self, format: str, *args: object) -> None:
        pass


def _wait_http(url: str, timeout_s: float) -> bytes:
    """GET ``url`` until it answers (a server starting), its body."""
    end = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                return bytes(r.read())
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.5)


def render(rrd: Path, png: Path, wait_s: float, width: int, height: int) -> None:
    """Open ``rrd`` in Rerun's web viewer in headless Chromium and write a ``width`` x ``height``
    window's capture to ``png`` after ``wait_s`` host seconds."""
    from websockets.sync.client import connect

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        sys.exit("render_rrd: chromium not found (Debian: apt-get install chromium)")
    rerun = Path(sys.executable).with_name("rerun")
    file_port, web_port, grpc_port, devtools_port = (_free_port() for _ in range(4))
    handler = functools.partial(_CorsHandler, directory=str(rrd.parent))
    files = http.server.ThreadingHTTPServer(("127.0.0.1", file_port), handler)
    threading.Thread(target=files.serve_forever, daemon=True).start()
    procs: list[subprocess.Popen[bytes]] = []
    try:
        procs.append(subprocess.Popen(
            [str(rerun), "--serve-web", "--web-viewer-port", str(web_port), "--port",
             str(grpc_port), "--bind", "127.0.0.1"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True))  # fmt: skip (its own group: the launcher forks the viewer)
        viewer = f"http://127.0.0.1:{web_port}/"
        _wait_http(viewer, 60)
        page = f"{viewer}?url=http://127.0.0.1:{file_port}/{rrd.name}"
        profile = tempfile.mkdtemp(prefix="render_rrd-")
        procs.append(subprocess.Popen(
            [chromium, "--headless=new", "--no-sandbox", "--enable-unsafe-swiftshader",
             "--use-angle=swiftshader", f"--window-size={width},{height}",
             f"--remote-debugging-port={devtools_port}", "--remote-allow-origins=*",
             f"--user-data-dir={profile}", page],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True))  # fmt: skip
        targets = json.loads(_wait_http(f"http://127.0.0.1:{devtools_port}/json", 60))
        ws_url = next(t["webSocketDebuggerUrl"] for t in targets if t.get("type") == "page")
        t0 = time.monotonic()
        while (left := wait_s - (time.monotonic() - t0)) > 0:
            print(f"render_rrd: capturing in {left:.0f} s", flush=True)
            time.sleep(min(30.0, left))
        with connect(ws_url, max_size=None) as ws:
            ws.send(json.dumps({"id": 1, "method": "Page.captureScreenshot",
                                "params": {"format": "png"}}))  # fmt: skip
            while True:
                answer = json.loads(ws.recv())
                if answer.get("id") == 1:
                    break
        if "result" not in answer:
            sys.exit(f"render_rrd: Chromium refused the capture: {answer.get('error')}")
        png.write_bytes(base64.b64decode(answer["result"]["data"]))
        print(f"render_rrd: {png} ({png.stat().st_size} bytes)")
    finally:
        for p in reversed(procs):  # each whole process group (rerun's launcher forks the viewer)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        files.shutdown()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("rrd", type=Path, help="the recording (.rrd)")
    p.add_argument("png", type=Path, help="the capture to write")
    p.add_argument("--wait", type=float, default=250.0, help="host s before the capture (250)")
    p.add_argument("--size", default="1600x1000", help="window WIDTHxHEIGHT (1600x1000)")
    a = p.parse_args()
    if not a.rrd.is_file():
        sys.exit(f"render_rrd: {a.rrd}: no such file")
    w, h = (int(x) for x in a.size.split("x"))
    render(a.rrd.resolve(), a.png, a.wait, w, h)


if __name__ == "__main__":
    main()
