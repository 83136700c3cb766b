"""Every call of loomlight.Client against a real server on loopback (conftest.py's `server`), with the arrays'
shapes and dtypes asserted and the values checked against something the package under test did not compute: the
C++ CLI (build/loomlight) talking to the same server, the formats documented in docs/tabulation.md and the .proto,
files decoded here with plain numpy, csv, xml, json and OpenImageIO, the test meshes' documented counts
(tests/data/meshes/README.md), physics (reciprocity, Beer-Lambert, quadratures of f) and the server's other calls.

Each test keeps its work small (tiny images, few samples) so the file runs in seconds on two cores."""
import csv
import io
import json
import math
import os
import re
import struct
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import loomlight
from conftest import SOURCE_DIR, cli

MESH_DIR = os.path.join(SOURCE_DIR, "tests", "data", "meshes")
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"


# ---- helpers computed independently of the package ----

def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def spherical(theta_deg, phi_deg):
    """(sin t cos p, sin t sin p, cos t) for angles in degrees (arrays broadcast)."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack(np.broadcast_arrays(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)), axis=-1)


def f32_text(v):
    """A float32 written with 9 significant digits: read back, the same float32 (what both clients send)."""
    return ",".join("%.9g" % x for x in np.asarray(v, dtype=np.float32))


def cli_eval(server, preset, wi, wo, fp64=False):
    """The C++ CLI's `eval` CSV (wix..woz, r, g, b[, t]) as a list of dicts of floats."""
    args = ["eval", "--preset", preset]
    if fp64:
        args.append("--fp64")
    for a, b in zip(wi, wo):
        args += ["--wi", f32_text(a), "--wo", f32_text(b)]
    rows = list(csv.DictReader(io.StringIO(cli(server, *args).stdout)))
    assert len(rows) == len(wi)
    return [{k: float(v) for k, v in row.items()} for row in rows]


def oiio_read(data, tmp_path, suffix):
    """An encoded image decoded with OpenImageIO directly (not through loomlight.images)."""
    import OpenImageIO as oiio
    path = os.path.join(str(tmp_path), "decoded" + suffix)
    with open(path, "wb") as f:
        f.write(data)
    image = oiio.ImageInput.open(path)
    assert image is not None, oiio.geterror()
    try:
        spec = image.spec()
        pixels = np.asarray(image.read_image(oiio.FLOAT), dtype=np.float32)
    finally:
        image.close()
    return pixels.reshape(spec.height, spec.width, spec.nchannels)


def oiio_write_exr(pixels, path):
    import OpenImageIO as oiio
    pixels = np.ascontiguousarray(pixels, dtype=np.float32)
    height, width, channels = pixels.shape
    output = oiio.ImageOutput.create(path)
    assert output is not None, oiio.geterror()
    assert output.open(path, oiio.ImageSpec(width, height, channels, oiio.FLOAT))
    assert output.write_image(pixels)
    output.close()
    with open(path, "rb") as f:
        return f.read()


def preset_params(client, preset):
    """A preset's parameters as ListModels gives them (every parameter, fully specified)."""
    for model in client.models().models:
        for p in model.presets:
            if p.name == preset:
                return {param.name: list(param.values) for param in p.params}
    raise KeyError(preset)


def assert_monotone(values):
    assert all(b >= a for a, b in zip(values, values[1:])), values


_MASK = (1 << 64) - 1


def _mix64(x):
    """splitmix64's finaliser, as SampleRequest.seed's comment names it (CounterRng over Mix64)."""
    x = (x + 0x9E3779B97F4A7C15) & _MASK
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK
    return x ^ (x >> 31)


def counter_rng_floats(seed, count):
    """SampleRequest's documented draws: query q's numbers d = 0, 1, 2 are CounterRng(seed, q).Uniform(d),
    53-bit doubles in [0, 1), rounded to float and kept below 1."""
    below_one = np.nextafter(np.float32(1), np.float32(0))
    out = np.empty((count, 3), np.float32)
    for q in range(count):
        key = _mix64(seed ^ _mix64(q))
        for d in range(3):
            u = (_mix64((key + 0x632BE59BD9B4E019 * (d + 1)) & _MASK) >> 11) * 2.0 ** -53
            out[q, d] = min(np.float32(u), below_one)
    return out


def upper_pairs(count, seed, min_cos=0.15):
    """Random direction pairs above the surface (numpy's own generator)."""
    rng = np.random.default_rng(seed)

    def one():
        v = unit(rng.normal(size=(count, 3)))
        v[:, 2] = np.maximum(np.abs(v[:, 2]), min_cos)
        return unit(v).astype(np.float32)

    return one(), one()


# ---- health, models, scenes ----

def test_health_is_serving(server, client):
    assert client.health() == "SERVING"
    assert cli(server, "health").stdout.split()[-1] == "SERVING"


def parse_cli_models(text):
    """`loomlight models` as {model: {"params": [(name, type)], "presets": [names]}} plus the yarn's presets."""
    models, current, section = {}, None, None
    yarn_presets = []
    for line in text.splitlines():
        if line.startswith("model "):
            current = models.setdefault(line[6:].split(":")[0], {"params": [], "presets": []})
            section = None
        elif line.startswith("yarn "):
            current, section = "yarn", None
        elif line in ("  parameters:", "  presets:"):
            section = line.strip(" :")
        elif line.startswith("    ") and section:
            tokens = line.split()
            if section == "parameters" and current != "yarn" and tokens[0] != "NAME":
                kind = "real list" if tokens[1:3] == ["real", "list"] else tokens[1]
                current["params"].append((tokens[0], kind))
            elif section == "presets":
                (yarn_presets if current == "yarn" else current["presets"]).append(tokens[0])
        elif not line.startswith("    "):
            section = None
    return models, yarn_presets


def test_models_match_the_cli_listing(server, client):
    response = client.models()
    assert isinstance(response, loomlight.pb.ListModelsResponse)
    text = cli(server, "models").stdout
    cli_models, cli_yarn_presets = parse_cli_models(text)
    assert {"microcylinder", "woven", "thin_layer", "fiber", "btf", "gltf_sheen", "openpbr"} <= set(cli_models)
    assert [m.name for m in response.models] == list(cli_models)
    type_names = {loomlight.pb.ParamSchema.TYPE_REAL: "real", loomlight.pb.ParamSchema.TYPE_INT: "int",
                  loomlight.pb.ParamSchema.TYPE_RGB: "rgb", loomlight.pb.ParamSchema.TYPE_REAL_LIST: "real list",
                  loomlight.pb.ParamSchema.TYPE_TEXT: "text"}
    for model in response.models:
        listed = cli_models[model.name]
        assert [(p.name, type_names[p.type]) for p in model.params] == listed["params"], model.name
        assert [p.name for p in model.presets] == listed["presets"], model.name
        for param in model.params:
            assert param.min_count <= param.max_count
            if param.type == loomlight.pb.ParamSchema.TYPE_RGB:
                assert param.min_count == param.max_count == 3
        # a preset specifies every parameter of its model (ListModels' Preset comment)
        for p in model.presets:
            assert {q.name for q in p.params} <= {q.name for q in model.params}
    # the schemas the client checks materials with are the ones it lists
    schemas = client.schemas()
    assert schemas.preset_models["linen_plain"] == "microcylinder"
    assert schemas.preset_models["gltf_velvet"] == "gltf_sheen"
    assert client.check("sheer_voile").name == "thin_layer"
    gltf = {p.name: p for p in schemas.models["gltf_sheen"].params}
    assert (gltf["roughness"].min, gltf["roughness"].max, list(gltf["roughness"].default_values)) == (0, 1, [0.8])
    assert [p.name for p in schemas.models["btf"].params][0] == "asset"
    # the server limits line: "Server limits: 1048576 queries per call, |w| within 0.0001 of 1"
    limits = re.search(r"limits: (\d+) queries per call, \|w\| within ([0-9.e-]+)", text)
    assert int(limits.group(1)) == response.max_queries_per_call
    assert float(limits.group(2)) == pytest.approx(response.unit_tolerance)
    assert [p.name for p in response.yarn.presets] == cli_yarn_presets
    assert schemas.models["fiber"].ambient and schemas.models["fiber"].fiber_axis_param == "axis"
    assert schemas.models["thin_layer"].transmission and schemas.models["woven"].spatially_varying


def test_scenes_match_the_cli_listing(server, client):
    response = client.scenes()
    assert isinstance(response, loomlight.pb.ListScenesResponse)
    text = cli(server, "scenes").stdout
    cli_names = re.findall(r"^scene (\S+) \(", text, flags=re.M)
    cli_objects = re.findall(r"^  objects: (.*)$", text, flags=re.M)
    assert [s.name for s in response.scenes] == cli_names
    assert "sphere" in cli_names and "cylinders" in cli_names
    for scene, objects in zip(response.scenes, cli_objects):
        assert " ".join(f"'{o}'" for o in scene.objects) == objects, scene.name
    assert "studio" in [p.name for p in response.lighting_presets]


# ---- evaluate ----

# One preset per model, with direction pairs that exercise it (thin_layer: a transmitted pair; fiber: the sphere).
EVAL_CASES = {
    "linen_plain": ([[0, 0.5, 0.8660254], [0.3, 0.1, 0.9486833], [-0.6, 0.0, 0.8]],
                    [[0, -0.5, 0.8660254], [-0.2, 0.4, 0.8944272], [0.28, 0.96, 0.0001]]),
    "cotton_twill": ([[0, 0.5, 0.8660254], [0.6, 0.0, 0.8]], [[0.3, -0.4, 0.8660254], [-0.6, 0.0, 0.8]]),
    "sheer_voile": ([[0, 0.6, 0.8], [0, 0, 1], [0.48, 0.64, 0.6]], [[0, -0.6, 0.8], [0, 0.6, -0.8], [0, 0, 1]]),
    "cotton": ([[0, 0.6, 0.8], [0.6, 0, -0.8], [1, 0, 0]], [[0, -0.6, 0.8], [0, 0.8, 0.6], [0, 0, 1]]),
    "gltf_velvet": ([[0, 0.5, 0.8660254], [0.8, 0, 0.6]], [[0, -0.5, 0.8660254], [0.8, 0, 0.6]]),
}


@pytest.mark.parametrize("precision", ["fp32", "fp64"])
@pytest.mark.parametrize("preset", sorted(EVAL_CASES))
def test_evaluate_agrees_with_the_cli(server, client, preset, precision):
    wi, wo = (unit(v).astype(np.float32) for v in EVAL_CASES[preset])
    f = client.evaluate(preset, wi, wo, precision=precision)
    assert f.shape == (len(wi), 3) and f.dtype == np.float32
    assert np.all(np.isfinite(f)) and np.all(f >= 0)
    rows = cli_eval(server, preset, wi, wo, fp64=precision == "fp64")
    expected = np.array([[row["r"], row["g"], row["b"]] for row in rows], dtype=np.float32)
    # the CLI prints f with 9 significant digits, which reads back to the same float32; both clients send the same
    # float32 directions to the same server, so only a kernel batched differently could move the last bits
    np.testing.assert_allclose(f, expected, rtol=1e-6, atol=1e-12)
    assert np.any(expected > 0)


def test_evaluate_fp64_is_close_to_fp32(client):
    wi, wo = upper_pairs(64, seed=3)
    f32 = client.evaluate("silk_shot", wi, wo)
    result = client.evaluate("silk_shot", wi, wo, precision="fp64", details=True)
    assert result.response.precision == loomlight.pb.PRECISION_FP64
    assert result.f.dtype == np.float32 and result.f.shape == (64, 3)
    np.testing.assert_allclose(result.f, f32, rtol=2e-3, atol=1e-6)


def test_evaluate_takes_one_direction_as_a_flat_triple(client):
    wi, wo = unit([0.2, 0.3, 0.9]).astype(np.float32), unit([-0.4, 0.1, 0.8]).astype(np.float32)
    single = client.evaluate("velvet", wi, wo)
    assert single.shape == (1, 3) and single.dtype == np.float32
    batch = client.evaluate("velvet", np.stack([wo, wi]), np.stack([wi, wo]))
    # a pair alone or in a batch is the same query
    np.testing.assert_allclose(single, batch[1:2], rtol=1e-6)


def test_evaluate_with_uv_is_the_btf_whose_mean_is_the_brdf(client):
    wi, wo = unit([0, 0.5, 0.866]), unit([0.3, -0.4, 0.866])
    n = 32
    u, v = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n)
    uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float32)
    wis, wos = np.tile(wi, (len(uv), 1)), np.tile(wo, (len(uv), 1))
    f = client.evaluate("cotton_twill", wis, wos, uv=uv)
    assert f.shape == (n * n, 3) and f.dtype == np.float32
    assert np.ptp(f[:, 0]) > 0.1 * f[:, 0].mean()  # spatially varying: the weave shows
    # uv is in pattern repeats: a whole repeat further is the same texel
    shifted = client.evaluate("cotton_twill", wis[:64], wos[:64], uv=uv[:64] + np.float32([1, 2]))
    np.testing.assert_allclose(shifted, f[:64], rtol=1e-3, atol=1e-6)
    # without uv the woven model returns "the BRDF, its mean over a repeat" (ListModels): the 32 x 32 midpoint
    # mean of the BTF over one repeat approximates it to well within 3% (measured: under 1%)
    brdf = client.evaluate("cotton_twill", wi, wo)
    np.testing.assert_allclose(f.mean(axis=0), brdf[0], rtol=0.03)


def test_evaluate_details_and_thin_layer_transmittance(server, client):
    wi = unit([[0, 0.6, 0.8], [0, 0, 1], [0.48, 0.64, 0.6], [0, 0, -1]]).astype(np.float32)
    wo = unit([[0, -0.6, 0.8], [0, 0.6, -0.8], [0, 0, 1], [0.6, 0, 0.8]]).astype(np.float32)
    result = client.evaluate("sheer_voile", wi, wo, details=True)
    assert isinstance(result, loomlight.Evaluation)
    assert result.f.shape == (4, 3) and result.f.dtype == np.float32
    assert result.transmittance.shape == (4,) and result.transmittance.dtype == np.float32
    assert result.model == "thin_layer"
    assert isinstance(result.approximation, str)
    assert set(result.seconds) == {"queue", "kernel", "total"}
    assert all(s >= 0 for s in result.seconds.values())
    assert result.batch_queries >= 4
    # the direct (unscattered) transmittance of a slab of optical thickness tau toward wo: exp(-tau / |cos|)
    tau = preset_params(client, "sheer_voile")["tau"][0]
    np.testing.assert_allclose(result.transmittance, np.exp(-tau / np.abs(wo[:, 2].astype(np.float64))), rtol=1e-5)
    rows = cli_eval(server, "sheer_voile", wi, wo)
    np.testing.assert_allclose(result.transmittance, [row["t"] for row in rows], rtol=1e-6)
    np.testing.assert_allclose(result.f, [[row["r"], row["g"], row["b"]] for row in rows], rtol=1e-6)
    assert np.all(result.f[1] > 0)  # wi and wo on opposite sides: the layer's diffuse transmission
    # a model without transmission has none
    assert client.evaluate("linen_plain", wi[:1], wo[:1], details=True).transmittance is None


def test_evaluate_ambient_of_a_fiber_is_its_integral(server, client):
    wo = unit([[0.2, 0.3, 0.9], [0.0, 0.0, 1.0], [0.6, -0.8, 0.0]]).astype(np.float32)
    ambient = client.evaluate("cotton", None, wo, ambient=True)
    assert ambient.shape == (3, 3) and ambient.dtype == np.float32
    rows = list(csv.DictReader(io.StringIO(cli(server, "eval", "--preset", "cotton", "--ambient",
                                               *sum((["--wo", f32_text(w)] for w in wo), [])).stdout)))
    np.testing.assert_allclose(ambient, [[float(r[c]) for c in "rgb"] for r in rows], rtol=1e-6)
    # the integral of f(wi, wo) cos(theta_i) over the sphere of wi, theta_i the fiber's longitudinal angle
    # (cos theta_i = sin of the angle between wi and the axis), by a midpoint quadrature equal-area in
    # (t, phi) about the axis (t = wi . axis = sin theta_i): 400 x 200 nodes, fine across the narrowest
    # longitudinal lobe (beta_r about 7 degrees), so within 1% (measured: 0.1%)
    axis = unit(preset_params(client, "cotton")["axis"])
    assert np.allclose(axis, [1, 0, 0])  # the preset's axis: t is wi.x
    nt, nphi = 400, 200
    t = -1 + (np.arange(nt) + 0.5) * 2 / nt
    phi = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    tt, pp = np.meshgrid(t, phi, indexing="ij")
    r = np.sqrt(1 - tt ** 2)
    wi = np.stack([tt, r * np.cos(pp), r * np.sin(pp)], axis=-1).reshape(-1, 3).astype(np.float32)
    cos_theta_i = np.sqrt(1 - tt.ravel() ** 2)
    for k in range(len(wo)):
        f = client.evaluate("cotton", wi, np.tile(wo[k], (len(wi), 1)))
        integral = (f * cos_theta_i[:, None]).sum(axis=0) * 4 * np.pi / len(wi)
        np.testing.assert_allclose(ambient[k], integral, rtol=0.01)


def test_reciprocal_models_are_reciprocal(client):
    wi, wo = upper_pairs(200, seed=11)
    reciprocal = [m for m in client.models().models if m.reciprocal]
    assert {m.name for m in reciprocal} >= {"gltf_sheen", "thin_layer"}
    for model in reciprocal:
        preset = model.presets[0].name
        forward = client.evaluate(preset, wi, wo)
        backward = client.evaluate(preset, wo, wi)
        assert np.any(forward > 0), preset
        np.testing.assert_allclose(forward, backward, rtol=1e-4, atol=1e-6 * forward.max(), err_msg=preset)
    # and one that the server says is not reciprocal is not, at least somewhere (the test can tell the difference)
    forward, backward = client.evaluate("velvet", wi, wo), client.evaluate("velvet", wo, wi)
    assert not np.allclose(forward, backward, rtol=1e-4)


# ---- sample ----

def test_sample_shapes_and_weight(client):
    n = 500
    wo = np.tile(unit([0.3, 0.2, 0.9]).astype(np.float32), (n, 1))
    s = client.sample("gltf_velvet", wo, seed=5)
    assert isinstance(s, loomlight.Samples) and s.model == "gltf_sheen"
    assert s.wi.shape == (n, 3) and s.wi.dtype == np.float32
    assert s.pdf.shape == (n,) and s.pdf.dtype == np.float32
    assert s.weight.shape == (n, 3) and s.weight.dtype == np.float32
    assert s.f.shape == (n, 3) and s.f.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(s.wi, axis=1), 1, atol=1e-5)
    assert np.all(s.wi[:, 2] > 0)  # a reflection model: wi over wo's hemisphere
    assert np.all(s.pdf > 0)
    # weight = f |cos theta_i| / pdf (a surface model), recomputed here
    np.testing.assert_allclose(s.weight, s.f * np.abs(s.wi[:, 2:3]) / s.pdf[:, None], rtol=1e-5, atol=1e-9)
    # f is Evaluate's f(wi, wo) for the pair returned
    np.testing.assert_allclose(s.f, client.evaluate("gltf_velvet", s.wi, wo), rtol=1e-6, atol=1e-12)


def test_sample_is_reproducible_and_takes_the_documented_random_numbers(client):
    n = 48
    wo = np.tile(unit([-0.2, 0.4, 0.8]).astype(np.float32), (n, 1))
    a = client.sample("linen_plain", wo, seed=12345)
    b = client.sample("linen_plain", wo, seed=12345)
    for name in ("wi", "pdf", "weight", "f"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.wi, client.sample("linen_plain", wo, seed=12346).wi)
    # the seed's numbers derived here from the .proto's description (CounterRng(seed, q).Uniform(0, 1, 2))
    random = counter_rng_floats(12345, n)
    c = client.sample("linen_plain", wo, random=random)
    for name in ("wi", "pdf", "weight", "f"):
        np.testing.assert_array_equal(getattr(c, name), getattr(a, name))
    # and other numbers: same numbers, same samples
    other = np.random.default_rng(1).random((n, 3)).astype(np.float32)
    d, e = client.sample("linen_plain", wo, random=other), client.sample("linen_plain", wo, random=other)
    np.testing.assert_array_equal(d.wi, e.wi)
    assert not np.array_equal(d.wi, a.wi)


def test_sample_mean_weight_is_the_directional_albedo(client):
    wo = unit([np.sin(np.radians(40)), 0, np.cos(np.radians(40))]).astype(np.float32)
    n = 20000
    s = client.sample("gltf_velvet", np.tile(wo, (n, 1)), seed=9)
    estimate = s.weight.astype(np.float64).mean(axis=0)
    standard_error = s.weight.astype(np.float64).std(axis=0) / math.sqrt(n)
    # The albedo by a cosine-weighted midpoint quadrature: wi = (sqrt(u1) cos 2 pi u2, sqrt(u1) sin 2 pi u2,
    # sqrt(1 - u1)) has density cos / pi, so the albedo is pi times the mean of f over a 64 x 128 grid of (u1, u2).
    u1, u2 = np.meshgrid((np.arange(64) + 0.5) / 64, (np.arange(128) + 0.5) / 128, indexing="ij")
    r, a = np.sqrt(u1.ravel()), 2 * np.pi * u2.ravel()
    wi = np.stack([r * np.cos(a), r * np.sin(a), np.sqrt(1 - u1.ravel())], axis=1).astype(np.float32)
    albedo = np.pi * client.evaluate("gltf_velvet", wi, np.tile(wo, (len(wi), 1))).astype(np.float64).mean(axis=0)
    assert np.all(albedo > 0.02) and np.all(albedo < 1)
    # Loose on purpose: the Monte Carlo mean is unbiased (the .proto) but random, so allow 5 standard errors
    # (a false failure about once in 10^6 runs per channel), plus 1% for the quadrature's own error on this
    # smooth, rough lobe.
    assert np.all(np.abs(estimate - albedo) <= 5 * standard_error + 0.01 * albedo), (estimate, albedo,
                                                                                   standard_error)


# ---- tabulate ----

def in_plane_directions(theta_i, theta_o, phi_deg):
    """docs/tabulation.md: the angle t in the plane at azimuth phi is (sin t cos phi, sin t sin phi, cos t); the
    light is at -theta_i."""
    ti, to = np.meshgrid(theta_i, theta_o, indexing="ij")
    return spherical(-ti, phi_deg).reshape(-1, 3), spherical(to, phi_deg).reshape(-1, 3)


def test_tabulate_in_plane_array_is_evaluate_at_the_bin_centres(client):
    count_i, count_o, phi = 3, 8, 30.0
    table = client.tabulate("linen_plain", {"in_plane": {"theta_i_count": count_i, "theta_o_count": count_o,
                                                         "phi_plane_deg": phi}})
    assert isinstance(table, loomlight.Table)
    assert table.grid == "in_plane" and table.dims == (count_i, count_o) and table.path is None
    assert table.model == "microcylinder" and table.queries_per_cell == 1
    assert table.values.shape == (count_i, count_o, 3) and table.values.dtype == np.float32
    theta_i = (np.arange(count_i) + 0.5) * 90 / count_i
    theta_o = -90 + (np.arange(count_o) + 0.5) * 180 / count_o
    wi, wo = in_plane_directions(theta_i, theta_o, phi)
    expected = client.evaluate("linen_plain", wi, wo).reshape(count_i, count_o, 3)
    assert np.any(expected > 0)
    # directions computed here in double and the server's own differ in the last bits of float
    np.testing.assert_allclose(table.values, expected, rtol=1e-4, atol=1e-7)

    # listed incidences and the full circle (a transmission model: the layer's glow below the surface)
    table = client.tabulate("sheer_voile", {"in_plane": {"theta_i_deg": [10, -50], "theta_o_count": 6,
                                                         "full_circle": True}})
    assert table.dims == (2, 6) and table.values.shape == (2, 6, 3)
    wi, wo = in_plane_directions([10, -50], -180 + (np.arange(6) + 0.5) * 360 / 6, 0.0)
    np.testing.assert_allclose(table.values.reshape(-1, 3), client.evaluate("sheer_voile", wi, wo), rtol=1e-4,
                               atol=1e-7)


def merl_directions(i, j, k):
    """docs/tabulation.md's MERL cell centres (phi_h = 0): d = wi in the frame where h is +z; wi = Ry(theta_h) d,
    wo the reflection of wi about h."""
    theta_h = np.radians(((i + 0.5) / 90) ** 2 * 90)
    theta_d, phi_d = np.radians(j + 0.5), np.radians(k + 0.5)
    d = np.array([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)])
    c, s = np.cos(theta_h), np.sin(theta_h)
    wi = np.array([c * d[0] + s * d[2], d[1], -s * d[0] + c * d[2]])
    h = np.array([s, 0, c])
    return wi, 2 * np.dot(wi, h) * h - wi


def test_tabulate_merl_binary_file(client, tmp_path):
    array = client.tabulate("gltf_velvet", "merl")
    assert array.grid == "merl" and array.dims == (90, 90, 180)
    assert array.values.shape == (90, 90, 180, 3) and array.values.dtype == np.float32
    progress = []
    path = str(tmp_path / "velvet.binary")
    table = client.tabulate("gltf_velvet", "merl", path=path, progress=lambda done, total: progress.append((done,
                                                                                                            total)))
    assert table.path == path and table.values is None and table.dims == (90, 90, 180)
    assert os.listdir(str(tmp_path)) == ["velvet.binary"]  # no .part left behind
    cells = 90 * 90 * 180
    assert progress and progress[-1] == (cells, cells)
    assert_monotone([done for done, _ in progress])
    assert {total for _, total in progress} == {cells}
    # the package's reader: f64, against the array (float32 values)
    merl = loomlight.read_merl(path)
    assert merl.shape == (90, 90, 180, 3) and merl.dtype == np.float64
    np.testing.assert_allclose(merl, array.values, rtol=1e-6, atol=1e-12)
    # and plain numpy by the documented layout: int32 dims, then R, G, B float64 blocks of f / scale
    assert os.path.getsize(path) == 12 + 3 * 8 * cells
    dims = np.fromfile(path, dtype="<i4", count=3)
    assert dims.tolist() == [90, 90, 180]
    blocks = np.fromfile(path, dtype="<f8", offset=12).reshape(3, 90, 90, 180)
    scale = np.array([1 / 1500, 1.15 / 1500, 1.66 / 1500])
    f = np.moveaxis(blocks, 0, -1) * scale
    np.testing.assert_allclose(f, array.values, rtol=1e-6, atol=1e-12)
    # a few cells against Evaluate at the documented half/difference centres (an isotropic model: one phi_h)
    cells_checked = [(10, 20, 30), (45, 5, 90), (70, 40, 170), (2, 60, 0)]
    wi, wo = zip(*(merl_directions(*c) for c in cells_checked))
    expected = client.evaluate("gltf_velvet", np.array(wi), np.array(wo))
    got = np.array([f[c] for c in cells_checked])
    np.testing.assert_allclose(got, expected, rtol=1e-3, atol=1e-6)


def test_tabulate_csv_file(client, tmp_path):
    grid = {"in_plane": {"theta_i_deg": [15, 45], "theta_o_count": 12, "phi_plane_deg": 90}}
    array = client.tabulate("silk_shot", grid)
    progress = []
    path = str(tmp_path / "lobe.csv")
    table = client.tabulate("silk_shot", grid, path=path, progress=lambda d, t: progress.append((d, t)))
    assert table.path == path and table.dims == (2, 12)
    assert os.listdir(str(tmp_path)) == ["lobe.csv"]
    assert progress[-1] == (24, 24)
    assert_monotone([d for d, _ in progress])
    with open(path, newline="") as f:
        reader = csv.reader(f)
        assert next(reader) == ["theta_i_deg", "theta_o_deg", "r", "g", "b"]
        rows = np.array([[float(x) for x in row] for row in reader])
    assert rows.shape == (24, 5)
    theta_o = -90 + (np.arange(12) + 0.5) * 180 / 12
    np.testing.assert_allclose(rows[:, 0], np.repeat([15, 45], 12))
    np.testing.assert_allclose(rows[:, 1], np.tile(theta_o, 2), atol=1e-6)
    # 9 significant digits: the float32 values exactly
    np.testing.assert_allclose(rows[:, 2:], array.values.reshape(-1, 3), rtol=1e-7, atol=1e-12)


# ---- texture slices ----

def test_texture_slice_array_exr_and_png(client, tmp_path):
    wi, wo = unit([0, 0.5, 0.866]), unit([0.3, -0.4, 0.866])
    width, height = 8, 6
    image = client.texture_slice("cotton_twill", wi, wo, width, height)
    assert image.shape == (height, width, 3) and image.dtype == np.float32
    assert np.all(np.isfinite(image)) and image.max() > 0
    # one repeat, the top row v = 1, u to the right: pixel (x, y) is Evaluate's BTF at its centre
    xs, ys = np.meshgrid(np.arange(width), np.arange(height))
    uv = np.stack([(xs.ravel() + 0.5) / width, 1 - (ys.ravel() + 0.5) / height], axis=1)
    f = client.evaluate("cotton_twill", np.tile(wi, (len(uv), 1)), np.tile(wo, (len(uv), 1)), uv=uv)
    np.testing.assert_allclose(image, f.reshape(height, width, 3), rtol=1e-5, atol=1e-8)

    exr = client.texture_slice("cotton_twill", wi, wo, width, height, format="exr")
    assert isinstance(exr, bytes) and exr[:4] == EXR_MAGIC
    decoded = oiio_read(exr, tmp_path, ".exr")
    assert decoded.shape == (height, width, 3)
    np.testing.assert_array_equal(decoded, image)

    png = client.texture_slice("cotton_twill", wi, wo, width, height, format="png")
    assert isinstance(png, bytes) and png[:8] == PNG_MAGIC
    assert oiio_read(png, tmp_path, ".png").shape[:2] == (height, width)


# ---- render ----

RENDER = dict(width=32, height=24, samples_per_pixel=2, seed=3)


def test_render_array_and_encoded_formats(client, tmp_path):
    progress = []
    r = client.render("linen_plain", "sphere", progress=lambda d, t: progress.append((d, t)), **RENDER)
    assert isinstance(r, loomlight.Rendering) and r.format == "array"
    assert r.image.shape == (24, 32, 3) and r.image.dtype == np.float32
    assert np.all(np.isfinite(r.image)) and np.all(r.image >= 0) and r.image.max() > 0
    assert (r.width, r.height) == (32, 24) and len(r.views) == 1
    # the server's own mean radiance over the image against the decoded array's
    np.testing.assert_allclose(r.image.astype(np.float64).mean(axis=(0, 1)), r.mean, rtol=1e-4)
    assert r.samples_per_pixel == (2, 2)
    assert progress and progress[-1][0] == progress[-1][1] == 32 * 24 * 2  # uniform sampling below 4 spp
    assert_monotone([d for d, _ in progress])
    # the fidelity report: per object of the scene, its choices
    sphere = next(s for s in client.scenes().scenes if s.name == "sphere")
    assert isinstance(r.fidelity, list) and all(isinstance(o, dict) for o in r.fidelity)
    assert [o["object"] for o in r.fidelity] == list(sphere.objects)
    assert r.fidelity[0]["model"] == "microcylinder"
    assert r.fidelity[0]["choices"] and all({"aspect", "chosen", "full"} <= set(c) for c in r.fidelity[0]["choices"])

    magic = {"png": lambda b: b[:8] == PNG_MAGIC, "jpeg": lambda b: b[:3] == b"\xff\xd8\xff",
             "webp": lambda b: b[:4] == b"RIFF" and b[8:12] == b"WEBP", "exr": lambda b: b[:4] == EXR_MAGIC}
    encoded = {}
    for fmt, check in magic.items():
        e = client.render("linen_plain", "sphere", format=fmt, **RENDER)
        assert isinstance(e.image, bytes) and check(e.image), fmt
        assert e.format == fmt and len(e.views) == 1
        encoded[fmt] = e.image
    # same request and seed: identical bytes, so the EXR decoded here is the array
    decoded = oiio_read(encoded["exr"], tmp_path, ".exr")
    assert decoded.shape == (24, 32, 3)
    np.testing.assert_array_equal(decoded, r.image)
    for fmt, suffix in (("png", ".png"), ("jpeg", ".jpg")):
        assert oiio_read(encoded[fmt], tmp_path, suffix).shape[:2] == (24, 32)


def test_render_transparent_background(client):
    r = client.render("linen_plain", "sphere", background="transparent", **RENDER)
    assert r.image.shape == (24, 32, 4) and r.image.dtype == np.float32
    alpha = r.image[:, :, 3]
    assert np.all((alpha >= 0) & (alpha <= 1))
    assert alpha[0, 0] == 0 and alpha[12, 16] == 1  # the corner misses the unit sphere, the centre hits it
    assert 0 < r.fill < 1


def test_render_turntable_views(client, tmp_path):
    r = client.render("linen_plain", "cylinders", views=3, format="exr", **RENDER)
    assert len(r.views) == 3 and len(r.response.views) == 3
    assert r.image == r.views[0]
    decoded = [oiio_read(v, tmp_path, ".exr") for v in r.views]
    assert all(d.shape == (24, 32, 3) for d in decoded)
    assert not np.array_equal(decoded[0], decoded[1])  # a row of cylinders seen from 120 degrees round
    arrays = client.render("linen_plain", "cylinders", views=3, **RENDER)
    assert len(arrays.views) == 3
    for array, expected in zip(arrays.views, decoded):
        assert array.shape == (24, 32, 3) and array.dtype == np.float32
        np.testing.assert_array_equal(array, expected)
    np.testing.assert_array_equal(arrays.image, arrays.views[0])


def test_mesh_upload_list_render_delete(client):
    name = "test_calls_uv_sphere"
    info = client.upload_mesh(name, os.path.join(MESH_DIR, "uv_sphere.glb"))
    # tests/data/meshes/README.md: 3,968 triangles, 2,143 vertices, one material `cloth`, UVs and normals
    assert (info.name, info.triangles, info.vertices) == (name, 3968, 2143)
    assert list(info.materials) == ["cloth"] and info.has_uvs and info.has_normals
    assert info.format == loomlight.pb.MESH_FORMAT_GLB
    np.testing.assert_allclose(info.bounds_min, [-1, -1, -1], atol=1e-5)
    np.testing.assert_allclose(info.bounds_max, [1, 1, 1], atol=1e-5)
    assert info.surface_area == pytest.approx(4 * np.pi, rel=0.02)  # a 64 x 32 UV sphere of radius 1
    try:
        listed = client.meshes()
        assert name in listed and listed[name].triangles == 3968
        r = client.render(mesh=name, materials={"cloth": "cotton_twill"}, width=24, height=24, samples_per_pixel=1)
        assert r.image.shape == (24, 24, 3) and r.image.dtype == np.float32
        assert np.all(np.isfinite(r.image)) and r.image.max() > 0
        assert [(o["object"], o["model"]) for o in r.fidelity] == [("mesh material 'cloth'", "woven")]
    finally:
        client.delete_mesh(name)
    assert name not in client.meshes()
    with pytest.raises(loomlight.NotFoundError):
        client.delete_mesh(name)


def test_render_an_inline_mesh(client):
    with open(os.path.join(MESH_DIR, "two_materials.obj"), "rb") as f:
        data = f.read()
    r = client.render(mesh=data, materials={"a": "linen_plain", "b": "gltf_velvet"}, width=24, height=24,
                      samples_per_pixel=1)
    assert r.image.shape == (24, 24, 3) and np.all(np.isfinite(r.image)) and r.image.max() > 0
    # the README: materials `a` and `b`, each wearing the material bound to it
    assert sorted((o["object"], o["model"]) for o in r.fidelity) == [("mesh material 'a'", "microcylinder"),
                                                                      ("mesh material 'b'", "gltf_sheen")]


# ---- yarn geometry ----

def read_pbrt_curves(path):
    """`loomlight yarn`'s pbrt-v4 file: per curve its comment (type, yarn, ply, fiber), width and points."""
    with open(path) as f:
        text = f.read()
    header = re.search(r"(\d+) fibers, (\d+) control points", text)
    comments = re.findall(r"^# (\w+) yarn (\d+) ply (\d+) fiber (-?\d+)$", text, flags=re.M)
    widths = [float(w) for w in re.findall(r'"float width0" \[ ([^ \]]+) \]', text)]
    points = [np.array(p.split(), dtype=np.float64).reshape(-1, 3)
              for p in re.findall(r'"point3 P" \[([^\]]*)\]', text)]
    return (int(header.group(1)), int(header.group(2))), comments, np.array(widths), points


def test_yarn_geometry_matches_the_cli(server, client, tmp_path):
    y = client.yarn_geometry("cotton1", straight={"length": 0.2})
    assert isinstance(y, loomlight.FiberCurves)
    n = len(y.point_counts)
    assert y.point_counts.dtype == np.uint32 and y.point_counts.shape == (n,)
    assert y.points.dtype == np.float32 and y.points.shape == (int(y.point_counts.sum()), 3)
    for name, dtype in (("widths", np.float32), ("types", np.int32), ("yarns", np.uint32), ("plies", np.uint32),
                        ("fibers", np.int32)):
        array = getattr(y, name)
        assert array.shape == (n,) and array.dtype == dtype, name
    assert y.summary.fibers == n and y.summary.control_points == len(y.points)
    assert np.all(y.points[:, 2] >= -1e-6) and np.all(y.points[:, 2] <= 0.2 + 1e-6)  # along +z, length 0.2

    path = str(tmp_path / "cotton1.pbrt")
    cli(server, "yarn", "--yarn", "cotton1", "--length", "0.2", "--out", path)
    (fibers, control_points), comments, widths, points = read_pbrt_curves(path)
    assert (fibers, control_points) == (n, len(y.points))
    assert len(comments) == len(points) == len(widths) == n
    type_names = {0: "core", 1: "migration", 2: "loop", 3: "hair"}  # FiberType
    assert [(type_names[t], int(a), int(b), int(c)) for t, a, b, c in zip(y.types, y.yarns, y.plies, y.fibers)] == \
        [(kind, int(a), int(b), int(c)) for kind, a, b, c in comments]
    np.testing.assert_allclose(widths, y.widths, rtol=1e-6)
    offsets = np.concatenate([[0], np.cumsum(y.point_counts.astype(np.int64))])
    for i, p in enumerate(points):
        # the CLI clamps each B-spline by repeating its end points twice more
        ours = y.points[offsets[i]:offsets[i + 1]]
        assert len(p) == len(ours) + 4
        np.testing.assert_allclose(p[2:-2], ours, rtol=1e-6, atol=1e-8)

    woven = client.yarn_geometry("cotton1", woven={"weave": "cotton_plain"}, detail={"footprint": 0.01})
    path = str(tmp_path / "woven.pbrt")
    cli(server, "yarn", "--yarn", "cotton1", "--weave", "cotton_plain", "--footprint", "0.01", "--out", path)
    (fibers, control_points), _, _, _ = read_pbrt_curves(path)
    assert (woven.summary.fibers, woven.summary.control_points) == (fibers, control_points)
    assert woven.summary.fibers == len(woven.point_counts) and int(woven.point_counts.sum()) == len(woven.points)
    assert {yarn.warp for yarn in woven.summary.yarns} == {True, False}


# ---- BTF assets ----

def btf_material(name):
    return loomlight.Material(model="btf", params={"asset": name})


def test_create_btf_list_evaluate_delete(client):
    name = "test_calls_created"
    rings = [{"theta": 0, "count": 1}, {"theta": 40, "count": 4}]
    progress = []
    asset = client.create_btf(name, "cotton_plain", grid={"rings": rings}, resolution=16,
                              compression={"max_components": 4}, replace=True,
                              progress=lambda stage, done, views: progress.append((stage, done, views)))
    try:
        assert asset.name == name and (asset.width, asset.height) == (16, 16) and asset.components == 4
        assert [(r.theta, r.count) for r in asset.grid.rings] == [(0, 1), (40, 4)]
        stages = [stage for stage, _, _ in progress]
        assert stages[0] == "synthesis" and stages[-1] == "done"
        assert stages == sorted(stages, key=["synthesis", "compression", "done"].index)
        assert {views for _, _, views in progress} == {5}  # one per view direction of the grid
        # (views_done is not asserted monotone: under load the server's compression workers report out of order,
        # e.g. 0, 1, 3, 4, 5, 2, which the .proto does not rule out)
        for stage in ("synthesis", "compression"):
            done = [d for s, d, _ in progress if s == stage]
            assert done and all(0 <= d <= 5 for d in done), stage
        assert progress[-1] == ("done", 5, 5)
        assert name in client.btfs() and client.btfs()[name].components == 4
        # four components for five lights keep every mean-centred light image: "at a grid pair and a texel
        # centre it returns the PCA's reconstruction exactly" (docs/btf-assets.md), so the woven material's own
        # BTF at the texel centres, sampled there
        wi, wo = spherical(40, 90), spherical(40, 180)
        xs, ys = np.meshgrid(np.arange(16), np.arange(16))
        uv = np.stack([(xs.ravel() + 0.5) / 16, (ys.ravel() + 0.5) / 16], axis=1)
        wis, wos = np.tile(wi, (len(uv), 1)), np.tile(wo, (len(uv), 1))
        f = client.evaluate(btf_material(name), wis, wos, uv=uv)
        assert f.shape == (256, 3) and f.dtype == np.float32
        woven = client.evaluate("cotton_plain", wis, wos, uv=uv)
        np.testing.assert_allclose(f, woven, rtol=1e-4, atol=1e-5 * woven.max())
    finally:
        client.delete_btf(name)
    assert name not in client.btfs()
    with pytest.raises(loomlight.NotFoundError):
        client.delete_btf(name)


def test_upload_btf_from_images_made_here(client, tmp_path):
    name = "test_calls_uploaded"
    directions = [spherical(0, 0)] + [spherical(45, 90 * j) for j in range(4)]
    width, height = 4, 3
    ys, xs = np.mgrid[0:height, 0:width]
    pattern = 1.0 + xs + 4 * ys  # every texel different, so a flipped or shifted tile would show

    def value(view, light):
        return np.stack([0.01 * pattern * (1 + view), 0.01 * pattern * (1 + light),
                         np.full(pattern.shape, 0.05)], axis=-1)

    images = [(directions[v], directions[l], oiio_write_exr(value(v, l), str(tmp_path / f"v{v}l{l}.exr")))
              for v in range(5) for l in range(5)]
    asset = client.upload_btf(name, images, width, height, grid={"rings": [{"theta": 0, "count": 1},
                                                                           {"theta": 45, "count": 4}]},
                              compression={"max_components": 4}, replace=True)
    try:
        assert isinstance(asset, loomlight.pb.BtfAssetInfo)
        assert (asset.name, asset.width, asset.height, asset.components) == (name, width, height, 4)
        assert name in client.btfs()
        # at the grid pairs and texel centres (the top row is v = 1) f is the uploaded value
        wi, wo, uv, expected = [], [], [], []
        for v in range(1, 5):
            for l in range(1, 5):
                for y in range(height):
                    for x in range(width):
                        wi.append(directions[l])
                        wo.append(directions[v])
                        uv.append([(x + 0.5) / width, 1 - (y + 0.5) / height])
                        expected.append(value(v, l)[y, x])
        f = client.evaluate(btf_material(name), np.array(wi), np.array(wo), uv=np.array(uv))
        np.testing.assert_allclose(f, expected, rtol=1e-4, atol=1e-6)
    finally:
        client.delete_btf(name)
    assert name not in client.btfs()


# ---- materials out ----

def test_fit_gltf_sheen_glb(client, tmp_path):
    path = str(tmp_path / "velvet.glb")
    fit = client.fit_material("gltf_velvet", "gltf_sheen", format="glb", path=path)
    assert isinstance(fit, loomlight.Fit)
    assert fit.file[:4] == b"glTF" and fit.file_extension == ".glb" and fit.path == path
    with open(path, "rb") as f:
        assert f.read() == fit.file
    assert len(fit.fits) == 1 and len(fit.materials) == 1
    one = fit.fits[0]
    assert one.error >= 0 and one.regions
    assert all(r.region and r.error >= 0 and 0 <= r.share <= 1 for r in one.regions)
    assert [r.error for r in one.regions] == sorted((r.error for r in one.regions), reverse=True)
    fitted = fit.materials[0]
    assert fitted.model == "gltf_sheen"
    # a gltf_sheen material fitted with the gltf_sheen lobe is itself: the preset's parameters (ListModels)
    assert one.error < 0.01
    for key, value in preset_params(client, "gltf_velvet").items():
        np.testing.assert_allclose(np.atleast_1d(fitted.params[key]), value, atol=2e-3, err_msg=key)
    # the GLB read here (glTF 2.0: 12-byte header, then a JSON chunk) carries the fitted factors
    magic, version, length = struct.unpack_from("<4sII", fit.file)
    assert (magic, version, length) == (b"glTF", 2, len(fit.file))
    chunk_length, chunk_type = struct.unpack_from("<I4s", fit.file, 12)
    assert chunk_type == b"JSON"
    document = json.loads(fit.file[20:20 + chunk_length])
    material = document["materials"][0]
    np.testing.assert_allclose(material["extensions"]["KHR_materials_sheen"]["sheenColorFactor"],
                               fitted.params["sheen_color"], rtol=1e-5)
    np.testing.assert_allclose(material["pbrMetallicRoughness"]["baseColorFactor"][:3],
                               fitted.params["base_color"], rtol=1e-5)
    # the fitted material evaluates as the original
    wi, wo = upper_pairs(32, seed=21, min_cos=0.3)
    np.testing.assert_allclose(client.evaluate(fitted, wi, wo), client.evaluate("gltf_velvet", wi, wo), rtol=1e-2,
                               atol=1e-4)


def test_fit_openpbr_mtlx(client, tmp_path):
    path = str(tmp_path / "linen.mtlx")
    fit = client.fit_material("linen_plain", "openpbr", path=path)  # the format from the extension
    assert fit.file_extension == ".mtlx"
    with open(path, "rb") as f:
        assert f.read() == fit.file
    root = ET.fromstring(fit.file)
    assert root.tag == "materialx"
    shader = root.find("open_pbr_surface")
    assert shader is not None
    inputs = {i.get("name"): i.get("value") for i in shader.findall("input")}
    fitted = fit.materials[0]
    assert fitted.model == "openpbr"
    base = [float(x) for x in inputs["base_color"].replace(",", " ").split()]
    np.testing.assert_allclose(base, fitted.params["base_color"], rtol=1e-4, atol=1e-6)
    one = fit.fits[0]
    assert one.error > 0 and one.regions and all(r.region for r in one.regions)
    assert sum(r.share for r in one.regions) == pytest.approx(1, abs=1e-6)
    wi, wo = upper_pairs(16, seed=5)
    f = client.evaluate(fitted, wi, wo)
    assert f.shape == (16, 3) and f.dtype == np.float32 and np.all(np.isfinite(f)) and np.all(f >= 0)
