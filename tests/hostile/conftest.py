"""The hostile-program harness: canaries a sandboxed program must never reach.

* a loopback **TCP and UDP** canary server (same port number, 127.0.0.1) that records every
  connection or datagram: any hit is an escape to the host's network;
* a **canary environment variable** (`CANARY_ENV`, secret-looking name) set in this process;
* **canary files**: one in a private temp dir outside any work dir, and a ``.env`` beside a fake
  project, each holding a unique value.

A hostile program gets the canaries' coordinates through placeholders (`fill`), tries its attack,
and the test then asserts with `leaks` / `survivors` that nothing came back.
"""

from __future__ import annotations

import os
import secrets
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

CANARY_ENV = "VISPHY_CANARY_API_KEY"


@dataclass
class Canary:
    port: int
    env_value: str
    file_path: Path
    file_value: str
    dotenv_path: Path
    dotenv_value: str
    tcp_hits: list[str] = field(default_factory=list)
    udp_hits: list[str] = field(default_factory=list)

    @property
    def hits(self) -> list[str]:
        return self.tcp_hits + self.udp_hits

    @property
    def secrets(self) -> list[str]:
        return [self.env_value, self.file_value, self.dotenv_value]

    def fill(self, source: str, marker: str = "") -> str:
        """Substitute the placeholders a hostile program uses."""
        return (source.replace("__CANARY_PORT__", str(self.port))
                .replace("__CANARY_FILE__", str(self.file_path))
                .replace("__CANARY_DOTENV__", str(self.dotenv_path))
                .replace("__CANARY_ENV_NAME__", CANARY_ENV)
                .replace("__MARKER__", marker))

    def leaks(self, *texts) -> list[str]:
        """Canary values found in any of ``texts`` (strings, bytes, lists of them, or Paths of
        files/trees to scan)."""
        found = []

        def scan(blob: bytes, where: str) -> None:
            for value in self.secrets:
                if value.encode() in blob:
                    found.append(f"{value[:6]}… in {where}")

        for item in texts:
            if item is None:
                continue
            if isinstance(item, Path):
                files = [item] if item.is_file() else [p for p in item.rglob("*") if p.is_file()]
                for f in files:
                    try:
                        scan(f.read_bytes(), str(f))
                    except OSError:
                        pass
            elif isinstance(item, (list, tuple)):
                found += self.leaks(*item)
            elif isinstance(item, bytes):
                scan(item, "bytes")
            else:
                scan(str(item).encode(), "text")
        return found


def _serve_tcp(sock: socket.socket, hits: list[str]) -> None:
    while True:
        try:
            conn, addr = sock.accept()
        except OSError:
            return
        hits.append(f"tcp from {addr}")
        try:
            conn.settimeout(0.5)
            conn.recv(4096)
            conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 6\r\n\r\ncanary")
        except OSError:
            pass
        finally:
            conn.close()


def _serve_udp(sock: socket.socket, hits: list[str]) -> None:
    while True:
        try:
            data, addr = sock.recvfrom(65536)
        except OSError:
            return
        hits.append(f"udp {len(data)} bytes from {addr}")


@pytest.fixture(scope="session")
def canary(tmp_path_factory):
    """Start the canary servers, set the canary env var and write the canary files."""
    tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    tcp.bind(("127.0.0.1", 0))
    port = tcp.getsockname()[1]
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", port))
    tcp.listen(64)
    secret_dir = tmp_path_factory.mktemp("canary-secret")
    project = tmp_path_factory.mktemp("canary-project")
    c = Canary(port=port, env_value="envcanary-" + secrets.token_hex(12),
               file_path=secret_dir / "secret.txt",
               file_value="filecanary-" + secrets.token_hex(12),
               dotenv_path=project / ".env", dotenv_value="dotenvcanary-" + secrets.token_hex(12))
    c.file_path.write_text(c.file_value)
    c.file_path.chmod(0o644)  # readable by anyone on the host: only the sandbox may stop a read
    c.dotenv_path.write_text(f"OPENAI_API_KEY={c.dotenv_value}\n")
    for target, hits in ((_serve_tcp, c.tcp_hits), (_serve_udp, c.udp_hits)):
        threading.Thread(target=target, args=(tcp if target is _serve_tcp else udp, hits),
                         daemon=True).start()
    old = os.environ.get(CANARY_ENV)
    os.environ[CANARY_ENV] = c.env_value
    # self-check: the canary really listens (else "zero hits" would prove nothing)
    with socket.create_connection(("127.0.0.1", port), timeout=2):
        pass
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.sendto(b"probe", ("127.0.0.1", port))
    probe.close()
    end = time.monotonic() + 2
    while (not c.tcp_hits or not c.udp_hits) and time.monotonic() < end:
        time.sleep(0.01)
    assert c.tcp_hits and c.udp_hits, "the canary servers do not record hits"
    c.tcp_hits.clear()
    c.udp_hits.clear()
    yield c
    tcp.close()
    udp.close()
    if old is None:
        os.environ.pop(CANARY_ENV, None)
    else:
        os.environ[CANARY_ENV] = old


def survivors(marker: str) -> list[str]:
    """Processes whose command line or environment mentions ``marker`` (a hostile program puts
    its marker into every process it spawns)."""
    out = []
    me = os.getpid()
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == me:
            continue
        try:
            cmdline = Path(f"/proc/{entry}/cmdline").read_bytes()
        except OSError:
            continue
        if marker.encode() in cmdline:
            shown = cmdline.replace(b"\0", b" ")[:120]
            out.append(f"{entry}: {shown!r}")
    return out


def wait_no_survivors(marker: str, timeout_s: float = 3.0) -> list[str]:
    """`survivors` after giving the kernel ``timeout_s`` to reap a killed namespace."""
    end = time.monotonic() + timeout_s
    found = survivors(marker)
    while found and time.monotonic() < end:
        time.sleep(0.05)
        found = survivors(marker)
    return found
