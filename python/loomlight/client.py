"""The Loomlight client: every call of the API with numpy arrays in and out.

One Client holds one gRPC channel (thread-safe: share it between threads). Materials are checked against the
server's schemas (ListModels, fetched once) before a call is sent; the server checks them again. Every failure is
a loomlight.LoomlightError carrying the gRPC status code and the server's message."""
import os
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional

import grpc
import numpy as np
from google.protobuf import message as _message

from . import images as _images
from . import tables
from ._api import health_pb2, pb, pb_grpc
from ._docs import with_rpc_doc
from .errors import LoomlightError, from_rpc_error, invalid_argument
from .materials import Material, Schemas, add_params, as_material

# The server's send and receive limit (server/api/service.h kMaxMessageBytes): a client that accepts less would
# fail on a large render or a large batch of evaluations the server allows.
MAX_MESSAGE_BYTES = 64 << 20
# Bytes per upload message (UploadMesh chunks); the server accepts any size up to its message limit.
UPLOAD_CHUNK_BYTES = 1 << 20

ProgressCallback = Callable[[int, int], None]


def _read_file(path, what):
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError as error:
        raise OSError(f"{what}: cannot read {path}: {error.strerror}") from None


def _file_bytes(value, what):
    """A file's bytes given as bytes, or read from a path on this machine."""
    return bytes(value) if isinstance(value, (bytes, bytearray)) else _read_file(value, what)


def _directions(value, name, columns=3):
    """An (N, columns) float32 array from anything array-like; one direction alone is N = 1."""
    array = np.asarray(value, dtype=np.float32)
    if array.ndim == 1 and array.shape[0] == columns:
        array = array[None, :]
    if array.ndim != 2 or array.shape[1] != columns:
        raise invalid_argument(f"{name}: an (N, {columns}) array is expected, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise invalid_argument(f"{name}: every value must be finite")
    return np.ascontiguousarray(array)


def _rows(values, columns):
    return np.asarray(values, dtype=np.float32).reshape(-1, columns)


def _enum_value(enum, value, where):
    """An enum's number from its number, its full name or the name without the enum's prefix ("png" for
    RENDER_FORMAT_PNG, "fp64" for PRECISION_FP64), case-insensitive."""
    if isinstance(value, int):
        if value not in enum.values_by_number:
            raise invalid_argument(f"{where}: {value} is not a {enum.name}")
        return value
    wanted = str(value).upper().replace("-", "_")
    if wanted in enum.values_by_name:
        return enum.values_by_name[wanted].number
    matches = [v for v in enum.values if v.name.endswith("_" + wanted)]
    if len(matches) == 1:
        return matches[0].number
    choices = ", ".join(v.name.lower() for v in enum.values)
    raise invalid_argument(f"{where}: '{str(value)[:64]}' is not a {enum.name} ({choices})")


def fill(message, fields, where=""):
    """Sets a request's fields from keyword values: nested messages as dicts or messages, enums by short name,
    Materials as loomlight.Material or preset names, Param lists as {name: value}. Unknown names are refused."""
    for key, value in fields.items():
        if value is None:
            continue
        descriptor = message.DESCRIPTOR.fields_by_name.get(key)
        if descriptor is None:
            raise TypeError(f"{where or message.DESCRIPTOR.name}: no field '{key}' in {message.DESCRIPTOR.full_name}")
        _assign(message, descriptor, value, f"{where}.{key}" if where else key)
    return message


def _assign(message, descriptor, value, where):
    repeated = descriptor.label == descriptor.LABEL_REPEATED
    if descriptor.message_type is not None:
        kind = descriptor.message_type.full_name
        if repeated:
            container = getattr(message, descriptor.name)
            if kind == "loomlight.v1.Param" and isinstance(value, dict):
                add_params(container, value)
                return
            if kind == "loomlight.v1.MaterialBinding" and isinstance(value, dict):
                for mesh_material, material in value.items():
                    binding = container.add(mesh_material=mesh_material)
                    binding.material.CopyFrom(as_material(material).to_proto())
                return
            for item in value:
                _assign_message(container.add(), item, where)
        else:
            _assign_message(getattr(message, descriptor.name), value, where)
    elif descriptor.enum_type is not None:
        if repeated:
            getattr(message, descriptor.name).extend(_enum_value(descriptor.enum_type, v, where) for v in value)
        else:
            setattr(message, descriptor.name, _enum_value(descriptor.enum_type, value, where))
    elif repeated:
        getattr(message, descriptor.name).extend(value)
    else:
        setattr(message, descriptor.name, value)


def _assign_message(target, value, where):
    if target.DESCRIPTOR.full_name == "loomlight.v1.Material" and not isinstance(value, dict):
        target.CopyFrom(as_material(value).to_proto())
    elif isinstance(value, _message.Message):
        target.CopyFrom(value)
    elif isinstance(value, dict):
        target.SetInParent()  # an empty dict still sets the field (a oneof's choice, e.g. straight={})
        fill(target, value, where)
    else:
        raise TypeError(f"{where}: a {target.DESCRIPTOR.name} is a dict or a loomlight.v1.{target.DESCRIPTOR.name}, "
                        f"not {type(value).__name__}")


def mesh_source(mesh, format="auto"):
    """A MeshSource: a stored mesh's name (str), or a glTF/OBJ file's bytes or path (os.PathLike) sent inline."""
    if isinstance(mesh, pb.MeshSource):
        return mesh
    if isinstance(mesh, str):
        return pb.MeshSource(name=mesh)
    data = _file_bytes(mesh, "mesh")
    return pb.MeshSource(data=pb.MeshData(format=_enum_value(pb.MeshFormat.DESCRIPTOR, format, "mesh.format"),
                                          data=data))


@dataclass
class Evaluation:
    """Evaluate's answer with its details (evaluate(..., details=True))."""
    f: np.ndarray                    # (N, 3) float32, 1/sr
    transmittance: Optional[np.ndarray]  # (N,) for models with transmission, else None
    model: str
    approximation: str
    seconds: Dict[str, float]        # queue, kernel, total
    batch_queries: int
    response: Any = field(repr=False)


@dataclass
class Samples:
    """Sample's answer: per query the sampled wi, its density, the weight f |cos| / pdf and f."""
    wi: np.ndarray      # (N, 3) float32, unit, toward the light
    pdf: np.ndarray     # (N,) float32, per steradian
    weight: np.ndarray  # (N, 3) float32
    f: np.ndarray       # (N, 3) float32, 1/sr
    model: str
    response: Any = field(repr=False)


@dataclass
class Table:
    """Tabulate's answer: the grid, and the values (array mode) or the file written (path mode)."""
    grid: str                   # "in_plane", "anisotropic" or "merl"
    dims: tuple                 # the grid's dimensions, slowest first
    model: str
    queries_per_cell: int
    values: Optional[np.ndarray]  # dims + (3,) float32 (array mode)
    path: Optional[str]         # the file written (path mode)
    kernel_seconds: float
    total_seconds: float


@dataclass
class Rendering:
    """Render's answer: the image (float32 linear array, or encoded bytes), every view of a turntable, and the
    fidelity report: per object, each modelling choice with its estimated error and reason (as dicts)."""
    image: Any                  # np.ndarray (height, width, 3 or 4) or bytes
    views: List[Any]            # every view's image (one for a still)
    format: str                 # "array", "png", "jpeg", "webp" or "exr"
    width: int
    height: int
    fidelity: List[Dict[str, Any]]
    rungs: List[Dict[str, Any]]
    mean: tuple                 # mean linear RGB radiance
    fill: float                 # the share of the image the product covers
    samples_per_pixel: tuple    # (fewest, most)
    seconds: Dict[str, float]   # setup, kernel, total
    response: Any = field(repr=False)
    background: str = "environment"  # the request's: "environment", "white" or "transparent"

    def _repr_png_(self):
        if not isinstance(self.image, np.ndarray):
            return _images.png_from_encoded(self.image)
        # Exposed as the server exposes its 8-bit renders; a white background (pixels of exactly 1) does not count.
        weights = None
        if self.image.shape[2] == 3 and self.background == "white":
            weights = (~np.all(self.image == 1.0, axis=2)).astype(np.float32)
        return _images.encode_png(self.image, weights=weights)


@dataclass
class FiberCurves:
    """YarnGeometry's answer: the fiber curves as flat arrays, curve i's points at points[offsets[i]:offsets[i+1]]."""
    summary: Any                # loomlight.v1.YarnGeometrySummary
    point_counts: np.ndarray    # (curves,) uint32
    points: np.ndarray          # (points, 3) float32
    widths: np.ndarray          # (curves,) float32, diameters
    types: np.ndarray           # (curves,) int32, loomlight.v1.FiberType
    yarns: np.ndarray           # (curves,) uint32
    plies: np.ndarray           # (curves,) uint32
    fibers: np.ndarray          # (curves,) int32 (-1: a core)
    total_seconds: float

    @property
    def offsets(self):
        return np.concatenate([[0], np.cumsum(self.point_counts, dtype=np.int64)])

    def curve(self, index):
        offsets = self.offsets
        return self.points[offsets[index]:offsets[index + 1]]


@dataclass
class Fit:
    """FitMaterial's answer: per fabric the fitted material and its error, and the exported file."""
    fits: List[Any]             # loomlight.v1.MaterialFit, worst region first in each
    materials: List[Material]   # each fit's material (model gltf_sheen or openpbr), ready to evaluate or render
    file: bytes                 # the .glb, .gltf or .mtlx (empty for format "none")
    file_extension: str
    path: Optional[str]


def _message_dicts(messages):
    from google.protobuf.json_format import MessageToDict
    try:  # protobuf 5.26 renamed the option that keeps zero-valued fields (an error of 0 stays in the report)
        return [MessageToDict(m, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)
                for m in messages]
    except TypeError:  # protobuf before 5.26 (Debian bookworm's 3.21)
        return [MessageToDict(m, preserving_proto_field_name=True, including_default_value_fields=True)
                for m in messages]


class Client:
    """A connection to a Loomlight server.

        Client("127.0.0.1:50051")                                    # plaintext (loopback)
        Client("render.example:50051", tls_ca="ca.pem", token=TOKEN)  # TLS, a bearer token

    tls_ca: a PEM file of the CA certificates to trust, or "system" for the system's; tls_cert and tls_key: the
    client's certificate for servers that require one (mutual TLS); token: the bearer token (only over TLS, as
    the server accepts it); timeout: each call's deadline in seconds (None: none); tls_server_name: the name the
    server's certificate must carry when it is not the target's host."""

    def __init__(self, target="127.0.0.1:50051", tls_ca=None, token=None, *, tls_cert=None, tls_key=None,
                 tls_server_name=None, timeout=None):
        options = [("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
                   ("grpc.max_send_message_length", MAX_MESSAGE_BYTES)]
        if tls_ca is None:
            if token is not None:
                raise ValueError("a token is sent only over TLS: give tls_ca (a CA file, or 'system')")
            if tls_cert is not None or tls_key is not None:
                raise ValueError("tls_cert and tls_key need tls_ca")
            self._channel = grpc.insecure_channel(target, options=options)
        else:
            if (tls_cert is None) != (tls_key is None):
                raise ValueError("tls_cert and tls_key go together")
            credentials = grpc.ssl_channel_credentials(
                root_certificates=None if tls_ca == "system" else _read_file(tls_ca, "tls_ca"),
                private_key=_read_file(tls_key, "tls_key") if tls_key else None,
                certificate_chain=_read_file(tls_cert, "tls_cert") if tls_cert else None)
            if token is not None:
                credentials = grpc.composite_channel_credentials(credentials,
                                                                 grpc.access_token_call_credentials(token))
            if tls_server_name:
                options.append(("grpc.ssl_target_name_override", tls_server_name))
            self._channel = grpc.secure_channel(target, credentials, options=options)
        self.target = target
        self.timeout = timeout
        self.stub = pb_grpc.LoomlightStub(self._channel)
        self._health = self._channel.unary_unary(
            "/grpc.health.v1.Health/Check", request_serializer=health_pb2.HealthCheckRequest.SerializeToString,
            response_deserializer=health_pb2.HealthCheckResponse.FromString)
        self._schemas = None
        self._lock = threading.Lock()

    # ---- the connection ----

    def close(self):
        self._channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _unary(self, method, request, timeout):
        """A call with one reply: a unary one, or a client-streaming one (`request` an iterator of messages, sent
        as it yields them). `method` is the stub's name for it, or the callable itself."""
        call = getattr(self.stub, method) if isinstance(method, str) else method
        try:
            return call(request, timeout=self._deadline(timeout))
        except grpc.RpcError as error:
            raise from_rpc_error(error) from None

    def _stream(self, method, request, timeout):
        """The messages of a server stream; an interrupted caller (an exception, Ctrl-C) cancels the call."""
        call = getattr(self.stub, method)(request, timeout=self._deadline(timeout))
        try:
            for message in call:
                yield message
        except grpc.RpcError as error:
            raise from_rpc_error(error) from None
        finally:
            call.cancel()  # no-op once the stream has ended

    def _deadline(self, timeout):
        return self.timeout if timeout is None else timeout

    def health(self, service="", timeout=None):
        """The server's health (grpc.health.v1): "SERVING", "NOT_SERVING" (e.g. a task stalled) or "UNKNOWN"."""
        response = self._unary(self._health, health_pb2.HealthCheckRequest(service=service), timeout)
        return health_pb2.HealthCheckResponse.ServingStatus.Name(response.status)

    # ---- models and materials ----

    @with_rpc_doc("ListModels", "ListModelsRequest")
    def models(self, refresh=False, timeout=None):
        """The server's models with their parameter schemas and presets, limits and yarn (ListModelsResponse),
        fetched once per Client (refresh=True fetches them again)."""
        return self.schemas(refresh, timeout).response

    def schemas(self, refresh=False, timeout=None):
        """The Schemas materials are checked against (fetched with ListModels on first use)."""
        with self._lock:
            if self._schemas is None or refresh:
                self._schemas = Schemas(self._unary("ListModels", pb.ListModelsRequest(), timeout))
            return self._schemas

    def material(self, preset="", model="", params=None, transmission=None, **kwargs):
        """A Material checked against the server's schema: a preset, a model with parameters, or a preset with
        some overridden. Parameters come as `params` {"thread1.albedo": (r, g, b)} or keywords, "__" standing for
        ".": material("silk_shot", thread1__albedo=(0.2, 0.5, 0.2)). Colours are linear RGB."""
        merged = dict(params or {})
        merged.update({name.replace("__", "."): value for name, value in kwargs.items()})
        result = Material(preset, model, merged, as_material(transmission) if transmission is not None else None)
        self.check(result)
        return result

    def check(self, material, where="material"):
        """Raises InvalidArgumentError (client_side=True) where the server's schema refuses the material; returns
        its model's ModelInfo."""
        return self.schemas().check(as_material(material), where)

    def _material_proto(self, material, where="material"):
        material = as_material(material)
        self.check(material, where)
        return material.to_proto()

    def _bind(self, container, panels, where):
        """{mesh material: material} into a repeated MaterialBinding, each material checked."""
        for index, (panel, material) in enumerate((panels or {}).items()):
            container.add(mesh_material=panel).material.CopyFrom(
                self._material_proto(material, f"{where}[{index}].material"))

    @with_rpc_doc("ListScenes", "ListScenesRequest")
    def scenes(self, timeout=None):
        """The render scenes with their parameters, default camera and lighting, and the lighting presets."""
        return self._unary("ListScenes", pb.ListScenesRequest(), timeout)

    # ---- BRDF queries ----

    @with_rpc_doc("Evaluate", "EvaluateRequest")
    def evaluate(self, material, wi, wo, uv=None, precision="fp32", *, error_target=0.0, fiber_axis=None,
                 ambient=False, details=False, timeout=None):
        """f(wi, wo) for N direction pairs: wi, wo (N, 3) unit vectors (toward the light, toward the viewer);
        uv (N, 2) for spatially varying materials; precision "fp32" or "fp64" (the double reference). Returns f as
        an (N, 3) float32 array in 1/sr (without the cosine); details=True returns an Evaluation with the
        transmittance, the approximation used and the timings. ambient=True: the ambient factor toward each wo
        (fiber models), wi then None."""
        request = pb.EvaluateRequest(material=self._material_proto(material),
                                     precision=_enum_value(pb.Precision.DESCRIPTOR, precision, "precision"),
                                     error_target=error_target,
                                     quantity=pb.QUANTITY_AMBIENT if ambient else pb.QUANTITY_SCATTERING)
        wo = _directions(wo, "wo")
        if not ambient:
            wi = _directions(wi, "wi")
            if wi.shape != wo.shape:
                raise invalid_argument(f"wi, wo: {len(wi)} and {len(wo)} directions; they go in pairs")
            request.wi.extend(wi.ravel())
        elif wi is not None:
            raise invalid_argument("wi: the ambient factor takes no wi")
        request.wo.extend(wo.ravel())
        if uv is not None:
            request.uv.extend(_directions(uv, "uv", 2).ravel())
        if fiber_axis is not None:
            request.fiber_axis.extend(_directions(fiber_axis, "fiber_axis").ravel())
        response = self._unary("Evaluate", request, timeout)
        f = _rows(response.f, 3)
        if not details:
            return f
        return Evaluation(f, np.asarray(response.transmittance, dtype=np.float32) if response.transmittance else None,
                          response.model, response.approximation,
                          {"queue": response.queue_seconds, "kernel": response.kernel_seconds,
                           "total": response.total_seconds}, response.batch_queries, response)

    @with_rpc_doc("Sample", "SampleRequest")
    def sample(self, material, wo, uv=None, *, random=None, seed=0, precision="fp32", error_target=0.0,
               timeout=None):
        """Importance-samples a wi for each wo (N, 3) from the material's own density: returns Samples with wi
        (N, 3), pdf (N,), weight f |cos| / pdf (N, 3) and f (N, 3). random (N, 3) numbers in [0, 1) replace the
        server's draws from seed."""
        wo = _directions(wo, "wo")
        request = pb.SampleRequest(material=self._material_proto(material), seed=seed,
                                   precision=_enum_value(pb.Precision.DESCRIPTOR, precision, "precision"),
                                   error_target=error_target)
        request.wo.extend(wo.ravel())
        if uv is not None:
            request.uv.extend(_directions(uv, "uv", 2).ravel())
        if random is not None:
            request.random.extend(_directions(random, "random").ravel())
        response = self._unary("Sample", request, timeout)
        return Samples(_rows(response.wi, 3), np.asarray(response.pdf, dtype=np.float32), _rows(response.weight, 3),
                       _rows(response.f, 3), response.model, response)

    @with_rpc_doc("Tabulate", "TabulateRequest")
    def tabulate(self, material, grid="merl", *, path=None, format=None, precision="fp32", progress=None,
                 timeout=None):
        """f on a grid of directions. grid: "merl", or {"merl": {...}}, {"in_plane": {...}} or
        {"anisotropic": {...}} with InPlaneGrid / AnisotropicGrid / MerlGrid fields. Without path: returns a Table
        whose values is a float32 array of the grid's dimensions + (3,). With path: streams the file there
        (format "raw", "exr", "merl" or "csv"; default from the path's extension) and returns a Table naming it.
        progress(cells_done, cells_total) is called as chunks arrive."""
        request = pb.TabulateRequest(material=self._material_proto(material),
                                     precision=_enum_value(pb.Precision.DESCRIPTOR, precision, "precision"))
        grids = {grid: {}} if isinstance(grid, str) else dict(grid)
        if len(grids) != 1:
            raise invalid_argument("grid: one of in_plane, anisotropic, merl")
        fill(request, grids)
        if path is None:
            if format not in (None, "raw"):
                raise invalid_argument("format: an array is read from the RAW table; give path to write other formats")
            request.format = pb.TABLE_FORMAT_RAW
        else:
            if format is None:
                format = {".exr": "exr", ".binary": "merl", ".csv": "csv"}.get(os.path.splitext(path)[1].lower(), "raw")
            request.format = _enum_value(pb.TableFormat.DESCRIPTOR, format, "format")
        first = last = None
        chunks = []
        partial = f"{path}.part" if path is not None else None
        output = open(partial, "wb") if partial else None
        try:
            for chunk in self._stream("Tabulate", request, timeout):
                first = first or chunk
                last = chunk
                if output:
                    output.write(chunk.data)
                else:
                    chunks.append(chunk.data)
                if progress:
                    progress(chunk.cells_done, chunk.cells_total)
            if output:
                output.close()
                os.replace(partial, path)
        except BaseException:
            if output:
                output.close()
                os.unlink(partial)
            raise
        if first is None:
            raise LoomlightError("Tabulate ended without a chunk")
        kind = request.WhichOneof("grid")
        values = None
        if path is None:
            kind, values = tables.read_raw(b"".join(chunks))
        return Table(kind, tuple(first.dims), first.model, first.queries_per_cell, values, path,
                     last.kernel_seconds, last.total_seconds)

    @with_rpc_doc("TextureSlice", "TextureSliceRequest")
    def texture_slice(self, material, wi, wo, width=256, height=256, *, region=None, samples_per_pixel=0,
                      format="array", precision="fp32", exposure=0.0, timeout=None):
        """An image of a spatially varying material's BTF over texture space for one wi and wo. region: (u_min,
        v_min, u_max, v_max) in pattern repeats (default one repeat). format "array": a (height, width, 3) float32
        array of linear f (1/sr); "png" or "exr": the encoded bytes."""
        request = pb.TextureSliceRequest(material=self._material_proto(material), width=width, height=height,
                                         samples_per_pixel=samples_per_pixel, exposure=exposure,
                                         precision=_enum_value(pb.Precision.DESCRIPTOR, precision, "precision"))
        request.wi.extend(_directions(wi, "wi").ravel())
        request.wo.extend(_directions(wo, "wo").ravel())
        if region is not None:
            u_min, v_min, u_max, v_max = region
            request.region.CopyFrom(pb.TextureRegion(u_min=u_min, v_min=v_min, u_max=u_max, v_max=v_max))
        request.format = pb.IMAGE_FORMAT_RAW if format == "array" else _enum_value(pb.ImageFormat.DESCRIPTOR, format,
                                                                                   "format")
        response = self._unary("TextureSlice", request, timeout)
        if format == "array":
            return _images.raw_rgb(response.image, response.width, response.height)
        return response.image

    # ---- renders ----

    @with_rpc_doc("Render", "RenderRequest")
    def render(self, material=None, scene="sphere", *, width=256, height=256, samples_per_pixel=0,
               format="array", mesh=None, materials=None, progress=None, timeout=None, **fields):
        """A thumbnail of a material on a scene (a ListScenes name: "sphere", "drape_stand", ...) or on a mesh
        (a stored mesh's name, or a glTF/OBJ file's bytes or path), `materials` {mesh material: material} dressing
        its panels. format "array": the image as a float32 linear (height, width, 3) array (4 channels with
        background="transparent"); "png", "jpeg", "webp", "exr": the encoded bytes. Other RenderRequest fields as
        keywords: lighting="studio", background="white", views=8, camera={...}, lights=[{...}], seed=1,
        scene_params={...}, error_target=0.02, ... progress(samples_done, samples_total) follows the stream.
        Returns a Rendering with the image, every view and the fidelity report."""
        request = pb.RenderRequest(width=width, height=height, samples_per_pixel=samples_per_pixel)
        if material is not None:
            request.material.CopyFrom(self._material_proto(material))
        if mesh is not None:
            request.mesh.CopyFrom(mesh_source(mesh))
        elif scene is not None:
            request.scene_name = scene
        self._bind(request.materials, materials, "materials")
        encoded = format != "array"
        request.format = _enum_value(pb.RenderFormat.DESCRIPTOR, format if encoded else "exr", "format")
        fill(request, fields)
        last = None
        for update in self._stream("Render", request, timeout):
            last = update
            if progress:
                progress(update.samples_done, update.samples_total)
        if last is None or not last.image:
            raise LoomlightError("Render ended without an image")
        views = [view.image for view in last.views] or [last.image]
        if not encoded:
            views = [_images.decode(image, ".exr") for image in views]
        return Rendering(views[0], views, format, last.width, last.height, _message_dicts(last.fidelity),
                         _message_dicts(last.rungs), tuple(last.mean), last.fill,
                         (last.min_samples_per_pixel, last.max_samples_per_pixel),
                         {"setup": last.setup_seconds, "kernel": last.kernel_seconds, "total": last.total_seconds},
                         last, pb.Background.Name(request.background).split("_", 1)[1].lower())

    # ---- yarn ----

    @with_rpc_doc("YarnGeometry", "YarnGeometryRequest")
    def yarn_geometry(self, yarn="cotton1", *, straight=None, woven=None, knit=None, curves=None, detail=None,
                      max_fibers=0, max_control_points=0, timeout=None):
        """A procedural yarn's fiber curves (Wu and Yuksel): yarn a preset name or {"preset", "params", "seed"};
        one layout of straight={"length"}, woven={...}, knit={...}, curves={"yarns": [...]} (none: one straight
        yarn). Returns FiberCurves with numpy arrays."""
        request = pb.YarnGeometryRequest(max_fibers=max_fibers, max_control_points=max_control_points)
        fill(request, {"yarn": {"preset": yarn} if isinstance(yarn, str) else yarn, "straight": straight,
                       "woven": woven, "knit": knit, "curves": curves, "detail": detail})
        summary, total = None, 0.0
        parts = {name: [] for name in ("point_counts", "points", "widths", "types", "yarns", "plies", "fibers")}
        for chunk in self._stream("YarnGeometry", request, timeout):
            if chunk.HasField("summary"):
                summary = chunk.summary
            for name, values in parts.items():
                values.append(getattr(chunk.curves, name))
            total = chunk.total_seconds or total

        def joined(name, dtype):
            return np.concatenate([np.asarray(v, dtype=dtype) for v in parts[name]]) if parts[name] else \
                np.zeros(0, dtype)

        return FiberCurves(summary, joined("point_counts", np.uint32), joined("points", np.float32).reshape(-1, 3),
                           joined("widths", np.float32), joined("types", np.int32), joined("yarns", np.uint32),
                           joined("plies", np.uint32), joined("fibers", np.int32), total)

    # ---- BTF assets ----

    @with_rpc_doc("CreateBtf", "CreateBtfRequest")
    def create_btf(self, name, material, *, grid=None, resolution=0, compression=None, replace=False, fibers=None,
                   progress=None, timeout=None):
        """Synthesises a BTF asset from a spatially varying material (or, with fibers={...}, from rendered fibers)
        and stores it on the server under `name`; returns its BtfAssetInfo. grid "h1", "h2" or {"rings": [...]};
        compression {"max_components", "target_psnr_db"}. progress(stage, views_done, views)."""
        request = pb.CreateBtfRequest(name=name, material=self._material_proto(material), resolution=resolution,
                                      replace=replace)
        fill(request, {"grid": {"preset": grid} if isinstance(grid, str) else grid, "compression": compression,
                       "fibers": fibers})
        asset = None
        for update in self._stream("CreateBtf", request, timeout):
            if progress:
                progress(update.stage, update.views_done, update.views)
            if update.HasField("asset"):
                asset = update.asset
        if asset is None:
            raise LoomlightError("CreateBtf ended without the asset")
        return asset

    @with_rpc_doc("UploadBtf", "UploadBtfHeader")
    def upload_btf(self, name, images, width, height, *, grid="h1", compression=None, replace=False,
                   value_scale=0.0, threads_per_tile=0.0, timeout=None):
        """Makes a BTF asset from images the client has: images an iterable of (view, light, data), view and
        light unit xyz (a grid direction each), data a PNG, EXR or JPEG file's bytes of f over the tile (top row
        v = 1). Returns the stored BtfAssetInfo."""
        header = pb.UploadBtfHeader(name=name, width=width, height=height, replace=replace, value_scale=value_scale,
                                    threads_per_tile=threads_per_tile)
        fill(header, {"grid": {"preset": grid} if isinstance(grid, str) else grid, "compression": compression})

        def messages():
            yield pb.UploadBtfMessage(header=header)
            for view, light, data in images:
                yield pb.UploadBtfMessage(image=pb.BtfImage(view=list(view), light=list(light), data=data))

        return self._unary("UploadBtf", messages(), timeout)

    @with_rpc_doc("ListBtfs", "ListBtfsRequest")
    def btfs(self, timeout=None):
        """The stored BTF assets (BtfAssetInfo each) by name."""
        return {asset.name: asset for asset in self._unary("ListBtfs", pb.ListBtfsRequest(), timeout).assets}

    @with_rpc_doc("DeleteBtf", "DeleteBtfRequest")
    def delete_btf(self, name, timeout=None):
        self._unary("DeleteBtf", pb.DeleteBtfRequest(name=name), timeout)

    # ---- meshes ----

    @with_rpc_doc("UploadMesh", "UploadMeshHeader")
    def upload_mesh(self, name, mesh, format="auto", *, timeout=None):
        """Stores a glTF 2.0 (.glb, or .gltf with embedded buffers) or OBJ file on the server under `name`, for
        render(mesh=name); mesh is the file's bytes or path. Returns its MeshInfo (materials, bounds, UVs...)."""
        data = _file_bytes(mesh, "mesh")
        header = pb.UploadMeshHeader(name=name, size=len(data),
                                     format=_enum_value(pb.MeshFormat.DESCRIPTOR, format, "format"))

        def messages():
            yield pb.UploadMeshMessage(header=header)
            for start in range(0, len(data), UPLOAD_CHUNK_BYTES):
                yield pb.UploadMeshMessage(chunk=data[start:start + UPLOAD_CHUNK_BYTES])

        return self._unary("UploadMesh", messages(), timeout)

    @with_rpc_doc("ListMeshes", "ListMeshesRequest")
    def meshes(self, timeout=None):
        """The stored meshes (MeshInfo each) by name."""
        return {mesh.name: mesh for mesh in self._unary("ListMeshes", pb.ListMeshesRequest(), timeout).meshes}

    @with_rpc_doc("DeleteMesh", "DeleteMeshRequest")
    def delete_mesh(self, name, timeout=None):
        self._unary("DeleteMesh", pb.DeleteMeshRequest(name=name), timeout)

    # ---- materials out ----

    @with_rpc_doc("FitMaterial", "FitMaterialRequest")
    def fit_material(self, material=None, target="gltf_sheen", *, format="none", path=None, mesh=None,
                     materials=None, colourways=None, name="", timeout=None):
        """Fits a material with a standard lobe (target "gltf_sheen" or "openpbr") and exports it (format "glb",
        "gltf", "mtlx" or "none"; written to path when given). mesh and materials ({mesh material: material})
        put it on a product; colourways {name: material or {"material", "bindings"}} make glTF variants.
        Returns a Fit: each fit's error by region, the fitted materials and the file's bytes."""
        if format == "none" and path is not None:
            format = {".glb": "glb", ".gltf": "gltf", ".mtlx": "mtlx"}.get(os.path.splitext(path)[1].lower(), "none")
        request = pb.FitMaterialRequest(name=name,
                                        target=_enum_value(pb.FitTarget.DESCRIPTOR, target, "target"),
                                        format=_enum_value(pb.ExportFormat.DESCRIPTOR, format, "format"))
        if path is not None and request.format == pb.EXPORT_FORMAT_NONE:
            raise invalid_argument("path: format 'none' writes no file")  # said before the fit, not after
        if material is not None:
            request.material.CopyFrom(self._material_proto(material))
        if mesh is not None:
            request.mesh.CopyFrom(mesh_source(mesh))
        self._bind(request.bindings, materials, "bindings")
        for index, (colourway, value) in enumerate((colourways or {}).items()):
            entry = request.colourways.add(name=colourway)
            spec = value if isinstance(value, dict) else {"material": value}
            if spec.get("material") is not None:
                entry.material.CopyFrom(self._material_proto(spec["material"], f"colourways[{index}].material"))
            self._bind(entry.bindings, spec.get("bindings"), f"colourways[{index}].bindings")
        response = self._unary("FitMaterial", request, timeout)
        if path is not None:
            with open(path, "wb") as f:
                f.write(response.file)
        return Fit(list(response.fits), [Material.from_proto(fit.fitted) for fit in response.fits], response.file,
                   response.file_extension, path)
