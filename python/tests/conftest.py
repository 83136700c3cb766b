"""Real Loomlight servers on loopback for the Python package's tests.

The build tree comes from $LOOMLIGHT_BUILD_DIR (CTest sets it; default ./build): its loomlight-server, loomlight
CLI and build/python package (on PYTHONPATH). `server` is a plaintext server, `tls_server` one that serves TLS with
the test certificates (tests/data/tls) and requires the test tokens; each has its own data directory."""
import os
import re
import subprocess
import time

import pytest

SOURCE_DIR = os.path.realpath(os.environ.get("LOOMLIGHT_SOURCE_DIR",
                                             os.path.join(os.path.dirname(__file__), "..", "..")))
BUILD_DIR = os.path.realpath(os.environ.get("LOOMLIGHT_BUILD_DIR", os.path.join(SOURCE_DIR, "build")))
TLS_DIR = os.path.join(SOURCE_DIR, "tests", "data", "tls")
EDITOR_TOKEN = "editor-token-0123456789abcdef"      # tests/data/tls/tokens.txt: every call
PIPELINE_TOKEN = "pipeline-token-0123456789abcdef"  # Render, ListModels and metrics only


class RunningServer:
    def __init__(self, process, port, log_path, data_dir):
        self.process, self.port, self.log_path, self.data_dir = process, port, log_path, data_dir
        self.target = f"127.0.0.1:{port}"

    def metrics_port(self):
        """The Prometheus port (servers started with --metrics-address 127.0.0.1:0)."""
        found = re.search(r"metrics on port (\d+)", self.log())
        return int(found.group(1)) if found else None

    def log(self):
        with open(self.log_path, encoding="utf-8", errors="replace") as f:
            return f.read()


def start_server(work, *extra):
    """Starts loomlight-server on a free loopback port (--address 127.0.0.1:0) and waits for its port line."""
    os.makedirs(work, exist_ok=True)
    log_path = os.path.join(work, "server.log")
    data_dir = os.path.join(work, "data")
    env = dict(os.environ, POCL_CACHE_DIR=os.environ.get("POCL_CACHE_DIR", os.path.join(BUILD_DIR, "pocl-cache")))
    with open(log_path, "w") as log:
        process = subprocess.Popen([os.path.join(BUILD_DIR, "loomlight-server"), "--address", "127.0.0.1:0",
                                    "--data-dir", data_dir, *extra], stdout=log, stderr=subprocess.STDOUT, env=env)
    deadline = time.monotonic() + 300  # a cold PoCL cache compiles the kernels first
    while True:
        with open(log_path, encoding="utf-8", errors="replace") as f:
            found = re.search(r"serving on port (\d+)", f.read())
        if found:
            return RunningServer(process, int(found.group(1)), log_path, data_dir)
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            with open(log_path) as f:
                pytest.fail(f"loomlight-server did not start:\n{f.read()[-3000:]}")
        time.sleep(0.1)


def stop_server(server):
    server.process.terminate()
    try:
        server.process.wait(timeout=30)
    except subprocess.TimeoutExpired:
        server.process.kill()


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    running = start_server(str(tmp_path_factory.mktemp("plain")), "--metrics-address", "127.0.0.1:0")
    yield running
    stop_server(running)


@pytest.fixture(scope="session")
def tls_server(tmp_path_factory):
    running = start_server(str(tmp_path_factory.mktemp("tls")),
                           "--tls-cert", os.path.join(TLS_DIR, "server.pem"),
                           "--tls-key", os.path.join(TLS_DIR, "server.key"),
                           "--tokens", os.path.join(TLS_DIR, "tokens.txt"))
    yield running
    stop_server(running)


@pytest.fixture()
def client(server):
    import loomlight
    with loomlight.Client(server.target, timeout=120) as connection:
        yield connection


def cli(server, *args, check=True):
    """Runs the C++ CLI (build/loomlight) against a server: an independent client to compare with."""
    result = subprocess.run([os.path.join(BUILD_DIR, "loomlight"), "--server", server.target, *args],
                            capture_output=True, text=True, timeout=300)
    if check and result.returncode != 0:
        raise AssertionError(f"loomlight {' '.join(args)} failed: {result.stderr}")
    return result
