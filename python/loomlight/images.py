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
        config = oiio.ImageSpec()
        config.attribute("oiio:UnassociatedAlpha", 1)  # the pixels as stored: PNG's alpha is not multiplied in
        image = oiio.ImageInput.open(path, config)
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


def automatic_exposure(rgb, weights=None):
    """0.18 / the geometric mean luminance of the pixels that are not black (each counted by its weight: coverage,
    or 0 for background), as the server exposes Render's 8-bit images (server/render/tone_map.h); 1 if none."""
    luminance = rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722
    weight = np.ones_like(luminance) if weights is None else np.clip(weights, 0.0, 1.0)
    use = (luminance > 1e-8) & np.isfinite(luminance) & (weight > 0)
    if not np.any(use):
        return 1.0
    exposure = 0.18 / np.exp(np.sum(weight[use] * np.log(luminance[use])) / np.sum(weight[use]))
    return float(exposure) if np.isfinite(exposure) and exposure > 0 else 1.0


def aces_filmic(x):
    """The ACES filmic fit the server's Render uses (Narkowicz 2015), into [0, 1]."""
    x = np.maximum(np.nan_to_num(np.asarray(x, dtype=np.float64), nan=0.0, posinf=1e30), 0.0)
    return np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


def _write_png(encoded):
    oiio = _oiio()
    height, width, channels = encoded.shape

    def write(path):
        output = oiio.ImageOutput.create(path)
        spec = oiio.ImageSpec(width, height, channels, oiio.UINT8)
        spec.attribute("oiio:UnassociatedAlpha", 1)  # the colour is the product's own, not multiplied by alpha
        output.open(path, spec)
        output.write_image(np.ascontiguousarray(encoded))
        output.close()
        with open(path, "rb") as f:
            return f.read()

    return _with_file(b"", ".png", write)


def encode_png(linear, exposure=None, weights=None):
    """A linear float image as PNG bytes, tone-mapped as the server maps Render's 8-bit images: exposure (default:
    automatic_exposure over the pixels, each counted by `weights`, or by the alpha channel when there is one), the
    ACES filmic curve, the sRGB curve. An alpha channel is kept as it is."""
    pixels = np.asarray(linear, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    if pixels.shape[2] == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    colour = pixels[:, :, :3]
    alpha = pixels[:, :, 3] if pixels.shape[2] == 4 else None
    if exposure is None:
        exposure = automatic_exposure(colour, weights if weights is not None else alpha)
    encoded = linear_to_srgb(aces_filmic(colour * exposure))
    if alpha is not None:
        encoded = np.concatenate([encoded, np.clip(alpha[:, :, None], 0, 1)], axis=2)
    return _write_png(np.round(encoded * 255.0).astype(np.uint8))


def png_from_encoded(data):
    """An 8-bit image the server encoded (PNG, JPEG, WebP) as PNG bytes, its pixels as they are (already
    tone-mapped and sRGB-encoded); an EXR (linear) is tone-mapped by encode_png."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return bytes(data)
    suffix = _suffix(data)
    if suffix == ".exr":
        return encode_png(decode(data, suffix))
    return _write_png(np.round(np.clip(decode(data, suffix), 0.0, 1.0) * 255.0).astype(np.uint8))


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
        shown = DisplayImage(png_from_encoded(bytes(image)))
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
