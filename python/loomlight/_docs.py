"""help() text from the .proto's own comments (proto_docs.json, written with the generated code)."""
import inspect
import json
import os

_DOCS_PATH = os.path.join(os.path.dirname(__file__), "v1", "proto_docs.json")
try:
    with open(_DOCS_PATH, encoding="utf-8") as _file:
        PROTO_DOCS = json.load(_file)
except OSError:  # generated code without its comments: help() shows the hand-written text alone
    PROTO_DOCS = {}

PACKAGE = "loomlight.v1"


def _indent(text, prefix="    "):
    return "\n".join(prefix + line if line else line for line in text.split("\n"))


def message_doc(descriptor):
    """A message's comment, then each field with its own."""
    lines = [PROTO_DOCS.get(descriptor.full_name, "")]
    fields = []
    for field in descriptor.fields:
        kind = field.message_type.name if field.message_type else (
            field.enum_type.name if field.enum_type else _SCALARS.get(field.type, "value"))
        if field.label == field.LABEL_REPEATED:
            kind = f"repeated {kind}"
        comment = PROTO_DOCS.get(f"{descriptor.full_name}.{field.name}", "")
        fields.append(f"{field.name} ({kind})" + (":\n" + _indent(comment) if comment else ""))
    if fields:
        lines.append("Fields:\n" + "\n".join(_indent(item) for item in fields))
    return "\n\n".join(line for line in lines if line)


def rpc_doc(method, request_descriptor):
    """The text help() shows for a Client method after its own: the RPC's comment and its request's fields."""
    comment = PROTO_DOCS.get(f"{PACKAGE}.Loomlight.{method}", "")
    return (f"\n\nServer call loomlight.v1.Loomlight/{method}" + (":\n" + _indent(comment) if comment else "") +
            f"\n\nRequest {request_descriptor.name}:\n" + _indent(message_doc(request_descriptor)))


def document_messages(module):
    """Gives every generated message class its .proto comment and fields as __doc__ (help(pb.RenderRequest))."""
    for descriptor in module.DESCRIPTOR.message_types_by_name.values():
        _document(getattr(module, descriptor.name), descriptor)


def _document(cls, descriptor):
    try:
        cls.__doc__ = message_doc(descriptor)
    except (AttributeError, TypeError):  # an implementation whose classes are immutable: help() shows the fields
        return
    for nested in descriptor.nested_types:
        _document(getattr(cls, nested.name), nested)


def with_rpc_doc(method, request_name):
    """Decorator: appends the RPC's and its request's .proto comments to a Client method's docstring."""
    def decorate(function):
        from ._api import pb
        function.__doc__ = inspect.cleandoc(function.__doc__ or "") + rpc_doc(method, pb.DESCRIPTOR.message_types_by_name[request_name])
        return function
    return decorate


_SCALARS = {1: "double", 2: "float", 3: "int64", 4: "uint64", 5: "int32", 8: "bool", 9: "string", 12: "bytes",
            13: "uint32"}
