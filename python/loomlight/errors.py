"""Errors of Loomlight calls: one exception type per gRPC status code, each carrying the code and the server's
message (or, for a request checked before it is sent, the client's, naming the field as the server would)."""
import grpc


class LoomlightError(Exception):
    """A Loomlight call failed. `code` is the grpc.StatusCode, `message` the server's explanation (it names the
    request field at fault), `client_side` whether the request was refused before it was sent."""

    code = grpc.StatusCode.UNKNOWN

    def __init__(self, message, code=None, client_side=False):
        super().__init__(message)
        if code is not None:
            self.code = code
        self.message = message
        self.client_side = client_side

    def __str__(self):
        return f"{self.code.name}: {self.message}"


class InvalidArgumentError(LoomlightError, ValueError):
    code = grpc.StatusCode.INVALID_ARGUMENT


class NotFoundError(LoomlightError, LookupError):
    code = grpc.StatusCode.NOT_FOUND


class AlreadyExistsError(LoomlightError):
    code = grpc.StatusCode.ALREADY_EXISTS


class PermissionDeniedError(LoomlightError, PermissionError):
    code = grpc.StatusCode.PERMISSION_DENIED


class UnauthenticatedError(LoomlightError, PermissionError):
    code = grpc.StatusCode.UNAUTHENTICATED


class ResourceExhaustedError(LoomlightError):
    code = grpc.StatusCode.RESOURCE_EXHAUSTED


class DeadlineExceededError(LoomlightError, TimeoutError):
    code = grpc.StatusCode.DEADLINE_EXCEEDED


class CancelledError(LoomlightError):
    code = grpc.StatusCode.CANCELLED


class UnavailableError(LoomlightError, ConnectionError):
    code = grpc.StatusCode.UNAVAILABLE


class FailedPreconditionError(LoomlightError):
    code = grpc.StatusCode.FAILED_PRECONDITION


_BY_CODE = {cls.code: cls for cls in (InvalidArgumentError, NotFoundError, AlreadyExistsError, PermissionDeniedError,
                                      UnauthenticatedError, ResourceExhaustedError, DeadlineExceededError,
                                      CancelledError, UnavailableError, FailedPreconditionError)}


def from_rpc_error(error):
    """The LoomlightError for a grpc.RpcError (its most specific subclass for the code)."""
    code = error.code() if callable(getattr(error, "code", None)) else grpc.StatusCode.UNKNOWN
    message = error.details() if callable(getattr(error, "details", None)) else str(error)
    return _BY_CODE.get(code, LoomlightError)(message or "", code=code)


def invalid_argument(message):
    """A request refused before it was sent, as the server would refuse it."""
    return InvalidArgumentError(message, client_side=True)
