"""TLS, bearer tokens and errors: every failure a LoomlightError subclass carrying the gRPC code and the message
naming the field, whether the server refused the request or the client's schema check did (before sending)."""
import os

import grpc
import numpy as np
import pytest

import loomlight
from conftest import EDITOR_TOKEN, PIPELINE_TOKEN, TLS_DIR

UP = [[0.0, 0.0, 1.0]]


def tls_client(server, token=None, ca="ca.pem", **kwargs):
    return loomlight.Client(server.target, tls_ca=os.path.join(TLS_DIR, ca), token=token, timeout=60, **kwargs)


# ---- TLS and tokens ----

def test_tls_with_a_token_serves_every_call_the_token_allows(tls_server):
    with tls_client(tls_server, EDITOR_TOKEN) as client:
        assert client.health() == "SERVING"
        f = client.evaluate("velvet", UP, UP)
        assert f.shape == (1, 3) and f.dtype == np.float32 and np.all(f > 0)


def test_a_token_limited_to_render_is_denied_evaluate_but_renders(tls_server):
    with tls_client(tls_server, PIPELINE_TOKEN) as client:
        with pytest.raises(loomlight.PermissionDeniedError) as denied:
            client.evaluate("velvet", UP, UP)
        assert denied.value.code == grpc.StatusCode.PERMISSION_DENIED
        assert "thumbs-pipeline" in denied.value.message and not denied.value.client_side
        picture = client.render("velvet", "sphere", width=8, height=8, samples_per_pixel=1)
        assert picture.image.shape == (8, 8, 3)


def test_tls_without_a_token_is_unauthenticated(tls_server):
    with tls_client(tls_server) as client:
        with pytest.raises(loomlight.UnauthenticatedError) as refused:
            client.models()
        assert refused.value.code == grpc.StatusCode.UNAUTHENTICATED and "bearer" in refused.value.message.lower()


def test_an_unknown_token_is_unauthenticated(tls_server):
    with tls_client(tls_server, "not-a-token-of-this-server") as client:
        with pytest.raises(loomlight.UnauthenticatedError):
            client.models()


def test_a_client_certificate_is_sent_when_given(tls_server):
    with tls_client(tls_server, EDITOR_TOKEN, tls_cert=os.path.join(TLS_DIR, "client.pem"),
                    tls_key=os.path.join(TLS_DIR, "client.key")) as client:
        assert client.health() == "SERVING"


def test_a_server_signed_by_another_ca_is_not_trusted(tls_server):
    with tls_client(tls_server, EDITOR_TOKEN, ca="other-ca.pem") as client:
        with pytest.raises(loomlight.UnavailableError) as failed:
            client.models(timeout=10)
        assert failed.value.code == grpc.StatusCode.UNAVAILABLE


def test_plaintext_to_a_tls_server_fails_unavailable(tls_server):
    with loomlight.Client(tls_server.target, timeout=10) as client:
        with pytest.raises(loomlight.UnavailableError):
            client.health()


def test_a_token_is_never_sent_in_plaintext():
    with pytest.raises(ValueError, match="only over TLS"):
        loomlight.Client("127.0.0.1:1", token=EDITOR_TOKEN)
    with pytest.raises(ValueError, match="go together"):
        loomlight.Client("127.0.0.1:1", tls_ca=os.path.join(TLS_DIR, "ca.pem"),
                         tls_cert=os.path.join(TLS_DIR, "client.pem"))


# ---- errors from the server ----

def test_the_server_names_the_field_of_a_bad_direction(client):
    with pytest.raises(loomlight.InvalidArgumentError) as refused:
        client.evaluate("velvet", [[0.0, 0.0, 2.0]], UP)
    error = refused.value
    assert error.code == grpc.StatusCode.INVALID_ARGUMENT and not error.client_side
    assert error.message.startswith("wi[0]") and isinstance(error, ValueError)
    assert str(error).startswith("INVALID_ARGUMENT: wi[0]")


def test_deleting_an_asset_that_does_not_exist_is_not_found(client):
    with pytest.raises(loomlight.NotFoundError) as missing:
        client.delete_btf("no_such_asset")
    assert missing.value.code == grpc.StatusCode.NOT_FOUND
    with pytest.raises(loomlight.NotFoundError):
        client.delete_mesh("no_such_mesh")


def test_a_passed_deadline_is_deadline_exceeded(client):
    with pytest.raises(loomlight.DeadlineExceededError) as late:
        client.render("velvet", "drape_stand", width=512, height=512, samples_per_pixel=256, timeout=0.05)
    assert late.value.code == grpc.StatusCode.DEADLINE_EXCEEDED and isinstance(late.value, TimeoutError)
    assert client.health() == "SERVING"  # the connection serves the next call


def test_a_render_on_a_mesh_that_is_not_stored_is_refused(client):
    with pytest.raises(loomlight.LoomlightError) as refused:
        client.render("velvet", mesh="no_such_mesh", width=8, height=8)
    assert refused.value.code in (grpc.StatusCode.NOT_FOUND, grpc.StatusCode.INVALID_ARGUMENT)
    assert "mesh" in refused.value.message


# ---- the client's own checks, against the server's schema ----

def send_unchecked(client, material):
    """The server's answer to the same material, sent by the generated stub without the client's check."""
    request = loomlight.pb.EvaluateRequest(material=material.to_proto(), wi=[0, 0, 1], wo=[0, 0, 1])
    with pytest.raises(grpc.RpcError) as refused:
        client.stub.Evaluate(request, timeout=60)
    return refused.value


@pytest.mark.parametrize("params, field", [
    ({"roughness": 0.5}, "material.params[0].name"),           # no such parameter in microcylinder
    ({"eta": 7.0}, "material.params[0]"),                       # outside [1, 3]
    ({"thread1.albedo": (0.5, 0.5)}, "material.params[0]"),     # an RGB parameter takes 3 values
    ({"eta": float("nan")}, "material.params[0]"),
    ({"eta": 1.5, "tangent_samples": 2.5}, "material.params[1]"),  # an integer parameter
])
def test_the_client_refuses_what_the_server_refuses_naming_the_same_field(client, params, field):
    material = loomlight.Material(preset="velvet", params=params)
    with pytest.raises(loomlight.InvalidArgumentError) as checked:
        client.evaluate(material, UP, UP)
    assert checked.value.client_side and checked.value.message.startswith(field)
    server_error = send_unchecked(client, material)
    assert server_error.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert server_error.details().startswith(field)


def test_unknown_presets_and_models_are_refused_before_sending(client):
    with pytest.raises(loomlight.InvalidArgumentError, match="material.preset"):
        client.material("no_such_preset")
    with pytest.raises(loomlight.InvalidArgumentError, match="material.model"):
        client.material(model="no_such_model")
    with pytest.raises(loomlight.InvalidArgumentError, match="material.model"):
        client.material("velvet", model="woven")  # velvet is a microcylinder preset


def test_a_valid_override_passes_the_check_and_changes_f(client):
    plain = client.evaluate("silk_shot", [[0.0, 0.5, 0.8660254]], [[0.0, -0.5, 0.8660254]])
    tinted = client.evaluate(client.material("silk_shot", thread1__albedo=(0.9, 0.1, 0.1),
                                             thread2__albedo=(0.9, 0.1, 0.1)),
                             [[0.0, 0.5, 0.8660254]], [[0.0, -0.5, 0.8660254]])
    assert tinted[0, 0] > tinted[0, 1] and not np.allclose(plain, tinted)


@pytest.mark.parametrize("wi, message", [
    ([[0.0, 1.0]], "wi: an (N, 3) array"),
    ([[0.0, np.nan, 1.0]], "wi: every value must be finite"),
    ([[0.0, 0.0, 1.0]] * 2, "wi, wo: 2 and 1 directions"),
])
def test_malformed_arrays_are_refused_before_sending(client, wi, message):
    with pytest.raises(loomlight.InvalidArgumentError) as refused:
        client.evaluate("velvet", wi, UP)
    assert refused.value.client_side and refused.value.message.startswith(message)


def test_enum_names_and_request_fields_are_checked(client):
    with pytest.raises(loomlight.InvalidArgumentError, match="format: 'gif' is not a RenderFormat"):
        client.render("velvet", width=8, height=8, format="gif")
    with pytest.raises(TypeError, match="no field 'colour'"):
        client.render("velvet", width=8, height=8, colour="red")


def test_a_fit_to_a_path_without_a_file_format_is_refused_before_the_fit(client, tmp_path):
    with pytest.raises(loomlight.InvalidArgumentError) as refused:
        client.fit_material("velvet", "gltf_sheen", path=str(tmp_path / "velvet.txt"))
    assert refused.value.client_side and refused.value.message.startswith("path: format 'none'")
    assert not (tmp_path / "velvet.txt").exists()


def test_bindings_are_checked_where_they_are_named(client):
    bad = loomlight.Material(preset="velvet", params={"eta": 9.0})
    with pytest.raises(loomlight.InvalidArgumentError) as refused:
        client.fit_material("velvet", colourways={"night": {"material": "velvet", "bindings": {"cloth": bad}}})
    assert refused.value.client_side
    assert refused.value.message.startswith("colourways[0].bindings[0].material.params[0]")
    with pytest.raises(loomlight.InvalidArgumentError) as refused:
        client.render(materials={"cloth": bad}, mesh="any_mesh", width=8, height=8)
    assert refused.value.message.startswith("materials[0].material.params[0]")


def test_scene_parameters_go_as_a_mapping(client):
    small, large = (client.render("velvet", "sphere", width=32, height=32, samples_per_pixel=1,
                                  background="transparent", scene_params={"radius": radius})
                    for radius in (0.5, 1.5))
    assert 0 < small.fill < large.fill  # the sphere's radius reached the scene
    with pytest.raises(loomlight.InvalidArgumentError) as refused:
        client.render("velvet", "sphere", width=8, height=8, scene_params={"no_such_parameter": 1})
    assert not refused.value.client_side and "scene_params" in refused.value.message
