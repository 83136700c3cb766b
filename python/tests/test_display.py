"""What notebooks show (Rendering._repr_png_, loomlight.display): the server's own 8-bit pixels for encoded
renders, and for float arrays the server's tone mapping (key exposure, ACES, sRGB) applied on the client."""
import numpy as np
import OpenImageIO as oiio

import loomlight


def png_pixels(data, tmp_path, name):
    path = tmp_path / name
    path.write_bytes(data)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # as stored: PNG's colour is not multiplied by its alpha
    image = oiio.ImageInput.open(str(path), config)
    pixels = image.read_image(oiio.UINT8)
    image.close()
    return np.asarray(pixels, dtype=np.int32)


def test_an_array_render_is_shown_as_the_server_tone_maps_it(client, tmp_path):
    request = dict(width=48, height=40, samples_per_pixel=4, seed=7)
    floats = client.render("velvet", "sphere", **request)
    server_png = client.render("velvet", "sphere", format="png", **request)
    mine = png_pixels(floats._repr_png_(), tmp_path, "mine.png")
    theirs = png_pixels(server_png.image, tmp_path, "theirs.png")
    assert mine.shape == theirs.shape == (40, 48, 3)
    assert np.abs(mine - theirs).max() <= 1  # rounding


def test_a_transparent_array_render_keeps_its_alpha_and_the_servers_curve(client, tmp_path):
    request = dict(width=48, height=48, samples_per_pixel=4, seed=7, background="transparent")
    floats = client.render("velvet", "drape_stand", **request)
    server_png = client.render("velvet", "drape_stand", format="png", **request)
    theirs = png_pixels(server_png.image, tmp_path, "theirs.png")
    # At the server's own exposure, the curve is the server's wherever the product covers a pixel whole. (The
    # automatic exposure differs a little: the server takes it from the coverage it keeps, the client from the
    # alpha channel; partly covered pixels are blended by the server's encoder.)
    mine = png_pixels(loomlight.images.encode_png(floats.image, exposure=server_png.response.exposure), tmp_path,
                      "mine.png")
    assert np.array_equal(mine[:, :, 3], theirs[:, :, 3])
    whole = theirs[:, :, 3] == 255
    assert whole.sum() > 100
    assert np.abs(mine[whole, :3] - theirs[whole, :3]).max() <= 1
    shown = png_pixels(floats._repr_png_(), tmp_path, "shown.png")
    assert np.array_equal(shown[:, :, 3], theirs[:, :, 3])


def test_encoded_renders_are_shown_with_their_own_pixels(client, tmp_path):
    for format, suffix in (("webp", ".webp"), ("jpeg", ".jpg"), ("png", ".png")):
        render = client.render("velvet", "sphere", width=32, height=32, samples_per_pixel=2, format=format)
        shown = loomlight.display(render).png
        assert np.array_equal(png_pixels(shown, tmp_path, "shown.png"),
                              png_pixels(render.image, tmp_path, "server" + suffix)), format
