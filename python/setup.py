"""Builds the package with its generated gRPC code (pyproject.toml holds the metadata).

The build step writes loomlight/v1/ (generate_proto.py) into the wheel from the .proto beside this directory
(../proto), or from $LOOMLIGHT_PROTO_DIR."""
import os
import sys

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from generate_proto import generate  # noqa: E402  (this directory's own script)


class BuildPyWithProto(build_py):
    def run(self):
        super().run()
        proto_dir = os.environ.get("LOOMLIGHT_PROTO_DIR", os.path.join(os.path.dirname(HERE), "proto"))
        if not os.path.isfile(os.path.join(proto_dir, "loomlight", "v1", "loomlight.proto")):
            sys.exit(f"loomlight: no loomlight/v1/loomlight.proto under {proto_dir}: build from a Loomlight checkout "
                     "(pip install ./python) or set LOOMLIGHT_PROTO_DIR")
        generate(self.build_lib, proto_dir)


setup(cmdclass={"build_py": BuildPyWithProto})
