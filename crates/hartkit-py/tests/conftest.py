"""Fixtures: the hartkit command line (HARTKIT_BIN, set by scripts/python-test), the
public test vectors, and a `hartkit serve --sim --hart-ip` on a free loopback port,
plain or with a PSK file."""

import contextlib
import os
import pathlib
import socket
import subprocess
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def hartkit_bin() -> str:
    path = os.environ.get("HARTKIT_BIN", str(ROOT / "target" / "debug" / "hartkit"))
    if not os.path.exists(path):
        pytest.fail(f"no hartkit binary at {path}: build it (cargo build -p hartkit) or set HARTKIT_BIN")
    return path


@pytest.fixture(scope="session")
def vectors():
    try:
        import tomllib
    except ImportError:  # Python < 3.11
        import tomli as tomllib
    with open(ROOT / "crates" / "hart-proto" / "tests" / "vectors" / "public.toml", "rb") as f:
        return tomllib.load(f)["vector"]


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve_hart_ip(hartkit_bin, *extra):
    """`hartkit serve --sim --hart-ip 127.0.0.1:PORT EXTRA...` in another process, up
    when it answers a TCP connect (it listens on both UDP and TCP). Yields the port."""
    port = free_port()
    proc = subprocess.Popen(
        [hartkit_bin, "serve", "--sim", "--hart-ip", f"127.0.0.1:{port}", *extra],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"hartkit serve did not start: {proc.stderr.read().decode()}")
                time.sleep(0.1)
        yield port
    finally:
        proc.kill()
        proc.wait()


@pytest.fixture
def hart_ip_server(hartkit_bin):
    """`hartkit serve --sim --hart-ip 127.0.0.1:PORT`: the demo plant behind a HART-IP
    server, in another process. Yields the udp:// target."""
    with serve_hart_ip(hartkit_bin) as port:
        yield f"udp://127.0.0.1:{port}"


PSK = "plant-host:00112233445566778899aabbccddeeff"


@pytest.fixture
def secure_hart_ip_server(hartkit_bin, tmp_path):
    """The same with `--psk-file` (HART-IP version 2: TLS over TCP, DTLS over UDP, key
    PSK), its devices answering at once (--instant). The server is the CLI (the
    system's OpenSSL, or whatever it was built with); the client is the installed
    wheel's own. Yields the port."""
    keys = tmp_path / "plant.psk"
    keys.write_text(PSK + "\n")
    with serve_hart_ip(hartkit_bin, "--instant", "--psk-file", str(keys)) as port:
        yield port
