"""The examples in python/examples, each run as a user runs it (a subprocess) against a real server; their
outputs are checked with other readers: OpenImageIO for the images, numpy for the MERL file, the C++ CLI for
what the server gives another client."""
import csv
import os
import shutil
import socket
import subprocess
import sys

import numpy as np
import pytest

from conftest import BUILD_DIR, SOURCE_DIR, cli

EXAMPLES = os.path.join(SOURCE_DIR, "python", "examples")
PYTHON = os.environ.get("LOOMLIGHT_PYTHON") or ("/usr/bin/python3" if os.path.exists("/usr/bin/python3")
                                                else sys.executable)


def run_example(name, *args, cwd, check=True):
    # PYTHONPATH as the tests' own (CTest sets build/python), made absolute since the example runs elsewhere; the
    # build tree's package when unset.
    env = dict(os.environ)
    paths = env.get("PYTHONPATH", "").split(os.pathsep) if env.get("PYTHONPATH") else [os.path.join(BUILD_DIR, "python")]
    env["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) for p in paths)
    result = subprocess.run([PYTHON, os.path.join(EXAMPLES, name), *args], cwd=cwd, env=env, capture_output=True,
                            text=True, timeout=600)
    if check and result.returncode != 0:
        raise AssertionError(f"{name} {' '.join(args)} exited {result.returncode}:\n{result.stdout}\n{result.stderr}")
    return result


def read_image(path):
    """(height, width, channels) float pixels through OpenImageIO, a reader independent of the package."""
    oiio = pytest.importorskip("OpenImageIO")
    image = oiio.ImageInput.open(path)
    assert image is not None, f"{path} does not decode: {oiio.geterror()}"
    try:
        return np.asarray(image.read_image(oiio.FLOAT))
    finally:
        image.close()


def read_summary(path):
    with open(path, newline="") as f:
        return {row["file"]: row for row in csv.DictReader(f)}


def product_colour(pixels):
    """Mean RGB of the pixels that are not the white background."""
    rgb = pixels[..., :3]
    product = rgb.min(axis=2) < 0.95
    assert product.mean() > 0.05, "the image shows next to no product"
    return rgb[product].mean(axis=0)


def test_thumbnail_batch_renders_the_catalogue_and_a_rerun_skips(server, tmp_path):
    out = tmp_path / "thumbs"
    args = [os.path.join(EXAMPLES, "catalogue.csv"), "--out", str(out), "--server", server.target, "--size", "96",
            "--workers", "3"]
    run_example("thumbnail_batch.py", *args, cwd=tmp_path)
    with open(os.path.join(EXAMPLES, "catalogue.csv"), newline="") as f:
        jobs = list(csv.DictReader(f))
    summary = read_summary(out / "summary.csv")
    assert len(jobs) >= 3 and len(summary) == len(jobs)
    for job in jobs:
        name = f"{job['product']}_{job['colourway']}.png"
        row = summary[name]
        assert row["status"] == "rendered" and row["error"] == "", row
        assert 0.0 <= float(row["fidelity"]) < 0.2 and float(row["seconds"]) > 0 and row["attempts"] == "1"
        pixels = read_image(str(out / name))
        assert pixels.shape[:2] == (96, 96)
        assert pixels[0, 0, :3].min() > 0.99, "background white: the corner is white"

    # The colourways' overrides reach the server: the emerald scarf is green, the garnet one red.
    emerald = product_colour(read_image(str(out / "scarf_emerald.png")))
    garnet = product_colour(read_image(str(out / "scarf_garnet.png")))
    assert emerald[1] > emerald[0] and garnet[0] > garnet[1], (emerald, garnet)

    # The same request from the C++ CLI gives the same picture: the example sends what the row says.
    cli(server, "render", "--preset", "silk_shot", "--param", "thread1.albedo=0.04,0.35,0.12",
        "--param", "thread2.albedo=0.02,0.12,0.06", "--scene", "drape_stand", "--size", "96x96",
        "--background", "white", "--lighting", "studio", "--out", str(tmp_path / "cli.png"))
    assert np.array_equal(read_image(str(tmp_path / "cli.png")), read_image(str(out / "scarf_emerald.png")))

    # A rerun renders only what is missing and keeps the earlier rows' measurements.
    missing = f"{jobs[0]['product']}_{jobs[0]['colourway']}.png"
    os.unlink(out / missing)
    kept = {name: os.stat(out / name).st_mtime_ns for name in summary if name != missing}
    run_example("thumbnail_batch.py", *args, cwd=tmp_path)
    rerun = read_summary(out / "summary.csv")
    assert rerun[missing]["status"] == "rendered"
    for name, mtime in kept.items():
        assert rerun[name]["status"] == "skipped" and rerun[name]["fidelity"] == summary[name]["fidelity"]
        assert os.stat(out / name).st_mtime_ns == mtime
    assert read_image(str(out / missing)).shape[:2] == (96, 96)


def test_thumbnail_batch_webp_meshes_and_failed_rows(server, tmp_path):
    shutil.copy(os.path.join(SOURCE_DIR, "tests", "data", "meshes", "uv_sphere.glb"), tmp_path / "ball.glb")
    catalogue = tmp_path / "jobs.csv"
    catalogue.write_text("product,colourway,preset,scene_or_mesh,params\n"
                         "ball,red,linen_plain,ball.glb,thread1.albedo=0.6 0.05 0.05; thread2.albedo=0.6 0.05 0.05\n"
                         "swatch,plain,cotton_twill,swatch,\n"
                         "swatch,typo,cotton_twill,swatch,warp.colour=0.1 0.1 0.1\n"
                         "swatch,nowhere,cotton_twill,no_such_scene,\n")
    result = run_example("thumbnail_batch.py", str(catalogue), "--out", str(tmp_path / "out"), "--server",
                         server.target, "--size", "64", "--format", "webp", cwd=tmp_path, check=False)
    assert result.returncode == 1, result.stdout + result.stderr  # some rows failed
    summary = read_summary(tmp_path / "out" / "summary.csv")
    for name in ("ball_red.webp", "swatch_plain.webp"):
        assert summary[name]["status"] == "rendered"
        with open(tmp_path / "out" / name, "rb") as f:
            header = f.read(12)
        assert header[:4] == b"RIFF" and header[8:12] == b"WEBP"
        assert read_image(str(tmp_path / "out" / name)).shape[:2] == (64, 64)
    red = product_colour(read_image(str(tmp_path / "out" / "ball_red.webp")))
    assert red[0] > 1.5 * red[1], red
    # A bad row fails alone, with the server's (or the schema's) words, and is not retried.
    typo = summary["swatch_typo.webp"]
    assert typo["status"] == "failed" and "INVALID_ARGUMENT" in typo["error"] and "warp.colour" in typo["error"]
    nowhere = summary["swatch_nowhere.webp"]
    assert nowhere["status"] == "failed" and "no_such_scene" in nowhere["error"] and nowhere["attempts"] == "1"
    assert not os.path.exists(tmp_path / "out" / "swatch_typo.webp")


def test_thumbnail_batch_retries_unavailable(tmp_path):
    # A port nothing listens on: every try is UNAVAILABLE, retried --retries times, then reported.
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    catalogue = tmp_path / "jobs.csv"
    catalogue.write_text("product,colourway,preset,scene_or_mesh\nscarf,plain,silk_shot,sphere\n")
    result = run_example("thumbnail_batch.py", str(catalogue), "--out", str(tmp_path / "out"), "--server",
                         f"127.0.0.1:{port}", "--retries", "2", "--backoff", "0.01", "--timeout", "20", cwd=tmp_path,
                         check=False)
    assert result.returncode == 1
    row = read_summary(tmp_path / "out" / "summary.csv")["scarf_plain.png"]
    assert row["status"] == "failed" and row["error"].startswith("UNAVAILABLE") and row["attempts"] == "3", row


def test_tabulate_merl_matches_the_cli_and_the_format(server, tmp_path):
    result = run_example("tabulate_merl.py", "--preset", "silk_shot", "--out", "silk.binary", "--server",
                         server.target, cwd=tmp_path)
    assert "largest relative difference" in result.stdout
    assert "100%" in result.stderr  # the progress callback saw the last chunk
    path = tmp_path / "silk.binary"
    # The MERL format as the proto documents it: int32 90 90 180, then float64 R, G, B blocks of f / scale.
    assert os.path.getsize(path) == 12 + 3 * 8 * 90 * 90 * 180
    assert np.fromfile(path, dtype="<i4", count=3).tolist() == [90, 90, 180]
    ours = np.fromfile(path, dtype="<f8", offset=12)
    # The C++ CLI writes the same table.
    cli(server, "--timeout", "600", "tab", "--preset", "silk_shot", "--grid", "merl", "--out",
        str(tmp_path / "cli.binary"))
    theirs = np.fromfile(tmp_path / "cli.binary", dtype="<f8", offset=12)
    np.testing.assert_allclose(ours, theirs, rtol=1e-6, atol=0)
    # A cell against the CLI's eval at its centre (theta_h index 20, theta_d 30, phi_d 90; phi_h = 0 + 7 more):
    # the mean over the 8 phi_h of an anisotropic model, f = stored value x MERL's scale.
    theta_h, theta_d, phi_d = np.radians([((20 + 0.5) / 90) ** 2 * 90, 30.5, 90.5])
    d = np.array([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)])
    rows = []
    for s in range(8):
        phi_h = 2 * np.pi * s / 8
        rotations = []
        for v in (d, d * [-1, -1, 1]):
            x, y, z = v[0] * np.cos(theta_h) + v[2] * np.sin(theta_h), v[1], -v[0] * np.sin(theta_h) + v[2] * np.cos(theta_h)
            rotations.append(f"{x * np.cos(phi_h) - y * np.sin(phi_h):.9f},{x * np.sin(phi_h) + y * np.cos(phi_h):.9f},"
                             f"{z:.9f}")
        rows.append(",".join(rotations))
    (tmp_path / "pairs.csv").write_text("\n".join(rows) + "\n")
    evaluated = cli(server, "eval", "--preset", "silk_shot", "--csv", str(tmp_path / "pairs.csv")).stdout
    f_cli = np.array([[float(v) for v in line.split(",")[6:9]] for line in evaluated.strip().split("\n")
                      if line[0] not in "wx"]).mean(axis=0)
    cell = (20 * 90 + 30) * 180 + 90
    stored = ours.reshape(3, -1)[:, cell] * np.array([1.0, 1.15, 1.66]) / 1500.0
    assert f_cli.max() > 0
    np.testing.assert_allclose(stored, f_cli, rtol=1e-4)


def test_display_render_writes_what_a_notebook_shows(server, tmp_path):
    result = run_example("display_render.py", "--preset", "velvet", "--scene", "sphere", "--size", "80", "--out",
                         "velvet.png", "--server", server.target, cwd=tmp_path)
    assert "wrote velvet.png" in result.stdout
    shown = read_image(str(tmp_path / "velvet.png"))
    linear = read_image(str(tmp_path / "velvet-linear.png"))
    assert shown.shape == (80, 80, 3) and linear.shape == (80, 80, 4)
    # The PNG a notebook draws is the server's: the CLI's render of the same request decodes the same.
    cli(server, "render", "--preset", "velvet", "--scene", "sphere", "--size", "80x80", "--background", "white",
        "--lighting", "studio", "--out", str(tmp_path / "cli.png"))
    assert np.array_equal(shown, read_image(str(tmp_path / "cli.png")))
    # The tone-mapped float render: transparent around the sphere, exposed so the product is neither black nor
    # clipped.
    alpha = linear[..., 3]
    assert alpha[0, 0] == 0 and alpha[40, 40] == 1
    product = linear[alpha == 1, :3]
    assert 0.1 < product.mean() < 0.9
