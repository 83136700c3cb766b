"""Loomlight from Python: cloth appearance models (BRDFs, BTFs, fibers) evaluated, sampled, tabulated and
rendered by a Loomlight server, with numpy arrays in and out.

    import loomlight
    with loomlight.Client("127.0.0.1:50051") as client:
        f = client.evaluate("silk_shot", wi=[[0, 0.5, 0.866]], wo=[[0, -0.5, 0.866]])   # (1, 3) float32, 1/sr
        picture = client.render(client.material("velvet"), "drape_stand", width=256, height=256)
        loomlight.display(picture)

help(loomlight.Client) documents every call with the server's own descriptions (from the .proto);
docs/python.md is the guide.
"""
from ._api import pb
from ._docs import document_messages as _document_messages
from .client import Client, Evaluation, FiberCurves, Fit, Rendering, Samples, Table
from .errors import (AlreadyExistsError, CancelledError, DeadlineExceededError, FailedPreconditionError,
                     InvalidArgumentError, LoomlightError, NotFoundError, PermissionDeniedError,
                     ResourceExhaustedError, UnauthenticatedError, UnavailableError)
from .images import display
from .materials import Material, Schemas
from .tables import read_merl, read_raw

_document_messages(pb)

__all__ = ["Client", "Material", "Schemas", "Evaluation", "Samples", "Table", "Rendering", "FiberCurves", "Fit",
           "LoomlightError", "InvalidArgumentError", "NotFoundError", "AlreadyExistsError", "PermissionDeniedError",
           "UnauthenticatedError", "ResourceExhaustedError", "DeadlineExceededError", "CancelledError",
           "UnavailableError", "FailedPreconditionError", "display", "read_merl", "read_raw", "pb"]
