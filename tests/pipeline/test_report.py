"""The report in a real headless browser (Debian's chromium), driven over the Chrome DevTools
protocol by the small stdlib websocket client below: the page loads without console errors,
uncaught exceptions or blocked resources, every <img> decodes (naturalWidth > 0), and the
accuracy-versus-time plots are there. Plus the page's content without a browser: self-contained
(no external URL), the best model named at a glance, and the SVG helpers.

Set-up: ``apt-get install -y --no-install-recommends chromium`` (the test set-up path). The
browser tests skip, saying why, only when chromium is not installed and cannot be installed.
"""
from __future__ import annotations

import base64
import json
import os
import re
import shutil
import socket
import struct
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from pipeline.plot import Series, pareto_mask, svg_plot
from pipeline.report import write_report

from .test_validate import tiny_artifacts  # noqa: F401  (the shared session fixture)

CHROME_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--no-first-run"]


# ------------------------------------------------------------------------------------- browser


def _find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def ensure_chromium() -> str:
    """The chromium binary, installed with apt when missing (as root or through sudo); skips the
    calling test, with the reason, only when that is impossible."""
    path = _find_chromium()
    if path:
        return path
    apt = shutil.which("apt-get")
    sudo = [] if os.geteuid() == 0 else (["sudo", "-n"] if shutil.which("sudo") else None)
    if apt is None or sudo is None:
        pytest.skip("chromium is not installed and cannot be installed here (no apt-get, or not root and no sudo)")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    proc = subprocess.run(sudo + [apt, "install", "-y", "-qq", "--no-install-recommends", "chromium"],
                          capture_output=True, text=True, env=env, timeout=900)
    path = _find_chromium()
    if path is None:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        pytest.skip(f"chromium could not be installed (apt-get exit {proc.returncode}: {tail[0]})")
    return path


class WebSocket:
    """A minimal RFC 6455 client over a plain socket (text frames, masked as clients must;
    fragmented and long frames; answers pings). Enough for the DevTools protocol."""

    def __init__(self, url: str, timeout: float = 30.0):
        m = re.match(r"ws://([^:/]+):(\d+)(/.*)", url)
        if not m:
            raise ValueError(f"not a ws:// URL: {url}")
        host, port, path = m.group(1), int(m.group(2)), m.group(3)
        self.sock = socket.create_connection((host, port), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError("websocket handshake: connection closed")
            head += chunk
        status = head.split(b"\r\n", 1)[0]
        if b" 101 " not in status:
            raise ConnectionError(f"websocket handshake refused: {status!r}")
        self.buf = head.split(b"\r\n\r\n", 1)[1]

    def _exact(self, n: int) -> bytes:
        while len(self.buf) < n:
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise ConnectionError("websocket closed")
            self.buf += chunk
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def _send_frame(self, opcode: int, payload: bytes) -> None:
        n = len(payload)
        head = bytes([0x80 | opcode])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 1 << 16:
            head += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack(">Q", n)
        mask = os.urandom(4)
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(head + mask + masked)

    def send(self, text: str) -> None:
        self._send_frame(0x1, text.encode())

    def recv(self) -> str:
        message = b""
        while True:
            b0, b1 = self._exact(2)
            opcode, n = b0 & 0x0F, b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._exact(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._exact(8))[0]
            mask = self._exact(4) if b1 & 0x80 else None
            data = self._exact(n)
            if mask:
                data = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
            if opcode == 0x9:  # ping
                self._send_frame(0xA, data)
                continue
            if opcode == 0x8:
                raise ConnectionError("websocket closed by the browser")
            message += data
            if b0 & 0x80:
                return message.decode()

    def close(self) -> None:
        try:
            self._send_frame(0x8, b"")
        except OSError:
            pass
        self.sock.close()


class Browser:
    """Headless chromium with a fresh profile and one page driven over DevTools; collects console
    errors, uncaught exceptions and error log entries (e.g. resources blocked or not found)."""

    def __init__(self, binary: str, timeout: float = 60.0):
        self.profile = Path(tempfile.mkdtemp(prefix="lumigraph-chromium-"))
        self.proc = subprocess.Popen([binary, *CHROME_FLAGS, f"--user-data-dir={self.profile}",
                                      "--remote-debugging-port=0", "about:blank"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.timeout, self.next_id, self.errors = timeout, 0, []
        port_file = self.profile / "DevToolsActivePort"
        deadline = time.monotonic() + timeout
        while not (port_file.is_file() and port_file.read_text().count("\n") >= 1):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise RuntimeError("chromium did not open its DevTools port")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        pages = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=timeout))
        page = next(p for p in pages if p.get("type") == "page")
        self.ws = WebSocket(page["webSocketDebuggerUrl"], timeout)
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable")

    def _event(self, msg: dict) -> None:
        method, p = msg.get("method"), msg.get("params", {})
        if method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            self.errors.append("console: " + " ".join(str(a.get("value", a.get("description", ""))) for a in p["args"]))
        elif method == "Runtime.exceptionThrown":
            d = p["exceptionDetails"]
            self.errors.append(f"exception: {d.get('text', '')} {d.get('exception', {}).get('description', '')}")
        elif method == "Log.entryAdded" and p["entry"].get("level") == "error":
            self.errors.append(f"log ({p['entry'].get('source')}): {p['entry'].get('text')}")

    def call(self, method: str, wait_event: str | None = None, **params) -> dict:
        """Send one command; return its result (after ``wait_event`` arrived, when given)."""
        self.next_id += 1
        my_id = self.next_id
        self.ws.send(json.dumps({"id": my_id, "method": method, "params": params}))
        result, seen = None, wait_event is None
        deadline = time.monotonic() + self.timeout
        while result is None or not seen:
            if time.monotonic() > deadline:
                raise TimeoutError(f"{method}: no answer within {self.timeout} s")
            msg = json.loads(self.ws.recv())
            if msg.get("id") == my_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                result = msg.get("result", {})
            elif "method" in msg:
                self._event(msg)
                seen = seen or msg["method"] == wait_event
        return result

    def evaluate(self, expression: str):
        r = self.call("Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"evaluate: {r['exceptionDetails'].get('text')}")
        return r["result"].get("value")

    def close(self) -> None:
        if getattr(self, "ws", None):
            self.ws.close()
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        shutil.rmtree(self.profile, ignore_errors=True)


@pytest.fixture(scope="module")
def browser():
    b = Browser(ensure_chromium())
    yield b
    b.close()


@pytest.fixture(scope="module")
def report(tiny_artifacts):  # noqa: F811
    return write_report(tiny_artifacts)


# ------------------------------------------------------------------------------------- tests

_PAGE_STATE = """
Promise.all([...document.images].map(i => i.decode().then(() => true, () => false))).then(decoded => ({
  images: [...document.images].map((i, k) => ({alt: i.alt, w: i.naturalWidth, h: i.naturalHeight,
                                                complete: i.complete, decoded: decoded[k]})),
  svgs: document.querySelectorAll('svg').length,
  circles: document.querySelectorAll('svg circle').length,
  h2: [...document.querySelectorAll('h2')].map(h => h.textContent),
  glance: (document.querySelector('.glance') || {}).textContent || ''
}))
"""


def test_report_loads_in_chromium_without_errors_and_decodes_its_images(browser, report, tiny_artifacts):  # noqa: F811
    browser.call("Page.navigate", wait_event="Page.loadEventFired", url=report.resolve().as_uri())
    state = browser.evaluate(_PAGE_STATE)
    assert browser.errors == []
    imgs = state["images"]
    models = json.loads((tiny_artifacts / "validate" / "metrics.json").read_text())["models"]
    views = json.loads((tiny_artifacts / "validate" / "manifest.json").read_text())["params"]["views"]
    # per shown view: reference render + noise, and render + error + Z-map + ꟻLIP map of every model
    assert len(imgs) == min(len(views), 4) * (2 + 4 * len(models))
    assert sum("ꟻLIP error" in i["alt"] for i in imgs) == min(len(views), 4) * len(models)
    bad = [i for i in imgs if not (i["complete"] and i["decoded"] and i["w"] > 0 and i["h"] > 0)]
    assert bad == []
    assert state["svgs"] >= 1 and state["circles"] >= len(models)
    assert {"Models at the held-out views", "Accuracy against time", "Side by side", "Pose accuracy"} <= set(state["h2"])
    assert "Best at the held-out views" in state["glance"]


def test_browser_test_catches_a_broken_page(browser, tmp_path):
    """The check can fail: a missing image and a script error are both seen."""
    page = tmp_path / "broken.html"
    page.write_text('<!DOCTYPE html><html><body><img src="missing.png"><script>undefinedCall()</script></body></html>')
    browser.errors.clear()
    browser.call("Page.navigate", wait_event="Page.loadEventFired", url=page.as_uri())
    state = browser.evaluate(_PAGE_STATE)
    assert any("undefinedCall" in e for e in browser.errors)
    assert state["images"][0]["w"] == 0 and not state["images"][0]["decoded"]
    browser.errors.clear()


def test_report_is_self_contained(report, tiny_artifacts):  # noqa: F811
    text = report.read_text()
    assert report.parent == tiny_artifacts / "validate"
    assert not re.search(r'(src|href)="(?!data:)', text)  # every image is a data URI, nothing linked
    assert "http://" not in text.replace("http://www.w3.org/2000/svg", "") and "https://" not in text
    best = json.loads((tiny_artifacts / "validate" / "metrics.json").read_text())["best"]["model"]
    assert f"Best at the held-out views: {best}" in text
    # the models table: display figures first, the all-black image's row with validate's black scores
    met = json.loads((tiny_artifacts / "validate" / "metrics.json").read_text())
    header = re.search(r"<table><tr>(.*?)</tr>", text.split("Models at the held-out views")[1]).group(1)
    assert re.findall(r"<th>(.*?)</th>", header)[2:5] == ["display PSNR dB", "subject display PSNR dB", "SSIM"]
    row = re.search(r'<tr class="black"><td>all-black image</td><td>–</td><td>([^<]*)</td>', text)
    assert row and row.group(1) == f"{met['reference']['black']['display_psnr_mean']:.2f}", row
    # moved elsewhere alone, it still has everything
    moved = shutil.copy(report, Path(tempfile.mkdtemp()) / "r.html")
    assert Path(moved).read_text() == text


def test_report_needs_a_finished_validate_stage(tmp_path):
    from pipeline.artifacts import BadInput

    with pytest.raises(BadInput, match="validate"):
        write_report(tmp_path)


def test_pareto_mask_against_brute_force():
    rng = np.random.default_rng(3)
    cost, acc = rng.integers(0, 6, 40).astype(float), rng.integers(0, 6, 40).astype(float)
    acc[5] = np.nan
    mask = pareto_mask(cost, acc)
    for i in range(40):
        dominated = any(cost[j] <= cost[i] and acc[j] >= acc[i] and (cost[j] < cost[i] or acc[j] > acc[i])
                        for j in range(40) if np.isfinite(acc[j]))
        assert mask[i] == (np.isfinite(acc[i]) and not dominated)


def test_svg_plot_is_finite_and_escaped():
    s = svg_plot([Series("a<b", [1.0, 10.0, float("nan")], [20.0, 30.0, 1.0], ["x&y", "z", "w"], line=True,
                         annotate=True), Series("empty", [], [])],
                 "time", "PSNR", "t", logx=True, hlines=[(35.0, "ceiling")])
    assert s.startswith("<svg") and s.rstrip().endswith("</svg>")
    assert "a&lt;b" in s and "x&amp;y" in s and "nan" not in s.lower().replace("nano", "")
    assert s.count("<circle") == 2
    assert "no data" in svg_plot([], "x", "y")


def test_report_on_a_stale_validate_stage_is_one_line_exit_2(tiny_artifacts, tmp_path):  # noqa: F811
    """A validate folder written before the display metrics: one line naming the file, exit 2."""
    import json
    import subprocess
    import sys

    art = tmp_path / "art"
    shutil.copytree(tiny_artifacts / "validate", art / "validate")
    f = art / "validate" / "metrics.json"
    met = json.loads(f.read_text())
    for row in met["models"].values():
        row.pop("display_psnr_mean")
    f.write_text(json.dumps(met))
    p = subprocess.run([sys.executable, "-m", "pipeline", "report", str(art), "--out", str(tmp_path / "r.html")],
                       capture_output=True, text=True)
    assert p.returncode == 2, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "display_psnr_mean" in p.stderr and "metrics.json" in p.stderr
    assert not (tmp_path / "r.html").exists()
