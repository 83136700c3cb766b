"""The generated protobuf and gRPC modules (python/generate_proto.py writes them at build time)."""
try:
    from .v1 import loomlight_pb2 as pb
    from .v1 import loomlight_pb2_grpc as pb_grpc
    from .v1 import health_pb2
except ImportError as error:  # a source checkout: the package is built by CMake (build/python) or pip
    raise ImportError(
        "loomlight's generated gRPC code is missing: use the build tree's package (PYTHONPATH=build/python after "
        "cmake --build build) or install it (pip install ./python)") from error

__all__ = ["pb", "pb_grpc", "health_pb2"]
