"""The package as a user gets it: `pip install ./python` into a virtual environment on Debian's python3-grpcio,
python3-protobuf and python3-numpy (the wheel's gRPC code generated from the .proto while it is built), help()
text from the .proto's comments, and nothing generated in the source tree."""
import os
import pydoc
import re
import shutil
import subprocess
import sys

import pytest

import loomlight
from conftest import SOURCE_DIR

PROTO = os.path.join(SOURCE_DIR, "proto", "loomlight", "v1", "loomlight.proto")


def proto_comment_above(pattern):
    """The // lines right above the first line of the .proto matching pattern, read here from the file itself."""
    with open(PROTO, encoding="utf-8") as f:
        lines = f.read().split("\n")
    index = next(i for i, line in enumerate(lines) if re.search(pattern, line))
    comment = []
    while lines[index - 1].strip().startswith("//"):
        index -= 1
        comment.insert(0, lines[index].strip()[2:].strip())
    return comment


def squash(text):
    return " ".join(text.split())


def test_pip_installs_the_package_into_a_virtual_environment(tmp_path, server):
    # A copy of python/ beside proto/, as a checkout has them, so the build writes nothing into the source tree.
    source = tmp_path / "src"
    shutil.copytree(os.path.join(SOURCE_DIR, "python"), source / "python",
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__", "v1"))
    shutil.copytree(os.path.join(SOURCE_DIR, "proto"), source / "proto")
    venv = tmp_path / "venv"
    python = os.environ.get("LOOMLIGHT_PYTHON", sys.executable)
    subprocess.run([python, "-m", "venv", "--system-site-packages", str(venv)], check=True)
    pip = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "--no-build-isolation", "--no-deps",
                          "--no-index", "--quiet", str(source / "python")], capture_output=True, text=True)
    assert pip.returncode == 0, pip.stdout + pip.stderr
    # Outside the source tree and without PYTHONPATH: the installed package alone.
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    script = ("import loomlight, os\n"
              "print(loomlight.__file__)\n"
              "c = loomlight.Client(%r)\n"
              "print(c.health())\n"
              "print(repr(c.evaluate('silk_shot', [0, 0.5, 0.8660254], [0, -0.5, 0.8660254]).tolist()))\n"
              % server.target)
    run = subprocess.run([str(venv / "bin" / "python"), "-c", script], cwd=str(tmp_path), env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    installed, health, values = run.stdout.strip().split("\n")
    assert installed.startswith(str(venv)), installed
    generated = os.path.join(os.path.dirname(installed), "v1")
    for name in ("loomlight_pb2.py", "loomlight_pb2_grpc.py", "health_pb2.py", "proto_docs.json"):
        assert os.path.isfile(os.path.join(generated, name)), name
    assert health == "SERVING"
    with loomlight.Client(server.target) as here:  # the build tree's package gives the same numbers
        assert eval(values) == here.evaluate("silk_shot", [0, 0.5, 0.8660254], [0, -0.5, 0.8660254]).tolist()


def test_nothing_generated_is_committed():
    if not os.path.isdir(os.path.join(SOURCE_DIR, ".git")):
        pytest.skip("not a git checkout")
    tracked = subprocess.run(["git", "-C", SOURCE_DIR, "ls-files", "python"], capture_output=True, text=True,
                             check=True).stdout.split()
    assert "python/loomlight/client.py" in tracked
    assert not [name for name in tracked if name.endswith(("_pb2.py", "_pb2_grpc.py", "proto_docs.json"))]


def test_help_shows_the_servers_own_description_of_each_call():
    text = squash(pydoc.render_doc(loomlight.Client.evaluate, renderer=pydoc.plaintext))
    assert squash(" ".join(proto_comment_above(r"^\s*rpc Evaluate\("))) in text
    assert squash(" ".join(proto_comment_above(r"^\s*Quantity quantity = 8;"))) in text  # a request field's
    render = squash(pydoc.render_doc(loomlight.Client.render, renderer=pydoc.plaintext))
    assert squash(" ".join(proto_comment_above(r"^\s*rpc Render\("))) in render


def test_help_on_a_message_shows_its_fields_comments():
    # pydoc draws a class's docstring behind " |  " margins: the margins are taken out before comparing.
    text = squash(pydoc.render_doc(loomlight.pb.RenderRequest, renderer=pydoc.plaintext).replace(" |  ", " "))
    assert squash(" ".join(proto_comment_above(r"^\s*string lighting = 31;"))) in text
    light = squash(pydoc.render_doc(loomlight.pb.RenderLight, renderer=pydoc.plaintext).replace(" |  ", " "))
    assert "type (Type)" in light and "direction (repeated double)" in light
