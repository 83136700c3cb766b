#!/usr/bin/env python3
"""Generates the Python gRPC code of the Loomlight API into a package tree, at build time.

    generate_proto.py --out DIR [--proto-dir DIR] [--protoc PROTOC] [--grpc-plugin PLUGIN] [--package-src DIR]

Writes DIR/loomlight/v1/: loomlight_pb2.py and loomlight_pb2_grpc.py (protoc with gRPC's own grpc_python_plugin,
from Debian's protobuf-compiler-grpc: the same gRPC as the server), health_pb2.py (grpc.health.v1's messages) and
proto_docs.json (every comment of the .proto, by full name, for help()). With --package-src, the hand-written
package (python/loomlight) is copied beside them first, so DIR alone is an importable package: the build tree's
build/python. setup.py calls generate() when pip builds the package; CMake runs this script for the build tree.
Nothing generated is committed.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_PROTO_DIR = os.path.join(os.path.dirname(HERE), "proto")
API_PROTO = "loomlight/v1/loomlight.proto"
HEALTH_PROTO = "health.proto"  # compiled from proto/grpc/health/v1: its messages only (see generate())


def _tool(name, given):
    found = given or shutil.which(name)
    if not found:
        sys.exit(f"generate_proto: {name} not found (Debian: apt-get install protobuf-compiler protobuf-compiler-grpc)")
    return found


def _comment_index(descriptor_set_bytes):
    """{full name: comment} for the services, methods, messages, fields, enums and values of the .proto."""
    from google.protobuf import descriptor_pb2
    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set_bytes)
    docs = {}
    for file in files.file:
        comments = {}
        for location in file.source_code_info.location:
            text = "\n".join(part.strip("\n") for part in (location.leading_comments, location.trailing_comments)
                             if part.strip())
            if text:
                comments[tuple(location.path)] = "\n".join(line[1:] if line.startswith(" ") else line
                                                           for line in text.split("\n"))
        prefix = file.package

        def enum(path, scope, index, value):
            name = f"{scope}.{value.name}"
            docs[name] = comments.get(path, "")
            for j, item in enumerate(value.value):
                docs[f"{name}.{item.name}"] = comments.get(path + (2, j), "")

        def message(path, scope, value):
            name = f"{scope}.{value.name}"
            docs[name] = comments.get(path, "")
            for j, field in enumerate(value.field):
                docs[f"{name}.{field.name}"] = comments.get(path + (2, j), "")
            for j, nested in enumerate(value.nested_type):
                message(path + (3, j), name, nested)
            for j, nested in enumerate(value.enum_type):
                enum(path + (4, j), name, j, nested)

        for i, value in enumerate(file.message_type):
            message((4, i), prefix, value)
        for i, value in enumerate(file.enum_type):
            enum((5, i), prefix, i, value)
        for i, service in enumerate(file.service):
            name = f"{prefix}.{service.name}"
            docs[name] = comments.get((6, i), "")
            for j, method in enumerate(service.method):
                docs[f"{name}.{method.name}"] = comments.get((6, i, 2, j), "")
    return {name: text for name, text in docs.items() if text}


def generate(out_dir, proto_dir=DEFAULT_PROTO_DIR, protoc=None, grpc_plugin=None):
    protoc = _tool("protoc", protoc)
    grpc_plugin = _tool("grpc_python_plugin", grpc_plugin)
    package = os.path.join(out_dir, "loomlight", "v1")
    os.makedirs(package, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        descriptors = os.path.join(scratch, "api.pb")
        subprocess.run([protoc, f"--proto_path={proto_dir}", f"--python_out={out_dir}", f"--grpc_python_out={out_dir}",
                        f"--plugin=protoc-gen-grpc_python={grpc_plugin}", "--include_source_info",
                        f"--descriptor_set_out={descriptors}", API_PROTO], check=True)
        # The health messages alone, beside the API's: grpc_python_plugin's stub would import `grpc.health.v1`,
        # which is grpcio's own package name, so the client calls the one method through the channel itself.
        subprocess.run([protoc, f"--proto_path={os.path.join(proto_dir, 'grpc', 'health', 'v1')}",
                        f"--python_out={package}", HEALTH_PROTO], check=True)
        with open(descriptors, "rb") as f:
            docs = _comment_index(f.read())
    with open(os.path.join(package, "proto_docs.json"), "w", encoding="utf-8") as f:
        json.dump(docs, f, indent=0, sort_keys=True)
    with open(os.path.join(package, "__init__.py"), "w", encoding="utf-8") as f:
        f.write('"""Generated from proto/loomlight/v1/loomlight.proto by python/generate_proto.py."""\n')


def copy_package(source, out_dir):
    """Mirrors the hand-written modules into out_dir/loomlight (leaving the generated v1/ in place)."""
    target = os.path.join(out_dir, "loomlight")
    os.makedirs(target, exist_ok=True)
    for name in os.listdir(source):
        if name.endswith(".py") or name == "py.typed":
            shutil.copyfile(os.path.join(source, name), os.path.join(target, name))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--proto-dir", default=DEFAULT_PROTO_DIR)
    parser.add_argument("--protoc")
    parser.add_argument("--grpc-plugin")
    parser.add_argument("--package-src", help="copy this hand-written package into OUT/loomlight first")
    args = parser.parse_args()
    if args.package_src:
        copy_package(args.package_src, args.out)
    generate(args.out, args.proto_dir, args.protoc, args.grpc_plugin)


if __name__ == "__main__":
    main()
