"""Images: decoding what the server sends into float32 numpy arrays, and showing images in notebooks.

OpenEXR is decoded by OpenImageIO's Python module (Debian: python3-openimageio), the library the server writes
it with; it is imported only when an EXR is decoded or a float image displayed."""
import os
import tempfile

import numpy as np


def _oiio():
    try:
        import OpenImageIO
    except ImportError as error:
        raise ImportError("decoding EXR images needs OpenImageIO's Python module (Debian: apt-get install "
                          "python3-openimageio); or ask for format='png', 'jpeg', 'webp' or 'exr' bytes") from error
    return OpenImageIO


def _with_file(data, suffix, action):
    # OpenImageIO's Python module reads and writes files: a private temporary file stands for the bytes.
    handle, path = tempfile.mkstemp(suffix=suffix)
    try:
        with os.fdopen(handle, "wb") as f:
            f.write(data)
        return action(path)
    finally:
        os.unlink(path)


def decode(data, suffix=".exr"):
    """An encoded image (EXR, PNG, JPEG, WebP) as a float32 array (height, width, channels); EXR values as stored
    (linear), 8-bit ones scaled to [0, 1] as stored (sRGB-encoded)."""
    oiio = _oiio()

    def read(path):
        image = oiio.ImageInput.open(path)
        if image is None:
            raise ValueError(f"not an image the server writes: {oiio.geterror()}")
        try:
            pixels = image.read_image(oiio.FLOAT)
        finally:
            image.close()
        return np.ascontiguousarray(pixels, dtype=np.float32)

    return _with_file(data, suffix, read)


def raw_rgb(data, width, height):
    """A RAW image (linear float32 RGB, little-endian, top row first) as a (height, width, 3) array."""
    expected = width * height * 3 * 4
    if len(data) != expected:
        raise ValueError(f"RAW image of {len(data)} bytes, {expected} expected for {width} x {height}")
    return np.frombuffer(data, dtype="<f4").reshape(height, width, 3).astype(np.float32)


def linear_to_srgb(linear):
    """The sRGB transfer curve (IEC 61966-2-1), values clipped to [0, 1] first."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def encode_png(linear, exposure=None):
    """A linear float image as PNG bytes: scaled by exposure (default: 1 over the 99th percentile of the
    brightest channel, as the server's automatic exposure), then sRGB-encoded to 8 bits."""
    oiio = _oiio()
    pixels = np.asarray(linear, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    colour = pixels[:, :, :3]
    if exposure is None:
        peak = float(np.percentile(colour.max(axis=2), 99)) if colour.size else 0.0
        exposure = 1.0 / peak if peak > 0 else 1.0
    encoded = linear_to_srgb(colour * exposure)
    if pixels.shape[2] == 4:  # keep the alpha (coverage) as it is
        encoded = np.concatenate([encoded, np.clip(pixels[:, :, 3:4], 0, 1)], axis=2)
    encoded = np.ascontiguousarray(np.round(encoded * 255.0).astype(np.uint8))
    height, width, channels = encoded.shape

    def write(path):
        output = oiio.ImageOutput.create(path)
        output.open(path, oiio.ImageSpec(width, height, channels, oiio.UINT8))
        output.write_image(encoded)
        output.close()
        with open(path, "rb") as f:
            return f.read()

    return _with_file(b"", ".png", write)


class DisplayImage:
    """Something a notebook shows as a picture (_repr_png_): an encoded PNG, or a float image tone-mapped to one."""

    def __init__(self, png):
        self.png = png

    def _repr_png_(self):
        return self.png


def display(image, exposure=None):
    """Shows a render, a texture slice or an image array in a notebook (IPython.display when present); returns
    an object whose _repr_png_ notebooks draw, so `display(x)` as a cell's last line also shows it."""
    png = getattr(image, "_repr_png_", None)
    if callable(png) and not isinstance(image, np.ndarray):
        shown = DisplayImage(png())
    elif isinstance(image, (bytes, bytearray)):
        if image[:8] != b"\x89PNG\r\n\x1a\n":
            image = encode_png(decode(bytes(image), _suffix(bytes(image))), exposure)
        shown = DisplayImage(bytes(image))
    else:
        shown = DisplayImage(encode_png(image, exposure))
    try:
        from IPython.display import display as ipython_display
    except ImportError:
        return shown
    ipython_display(shown)
    return shown


def _suffix(data):
    if data[:4] == b"\x76\x2f\x31\x01":
        return ".exr"
    if data[:3] == b"\xff\xd8\xff":
        return ".jpg"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return ".webp"
    return ".png"
