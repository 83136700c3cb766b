#!/usr/bin/env python3
"""Shows renders in a notebook, and writes the same pictures as PNG files when run as a script.

In Jupyter, paste the cells (the `# %%` blocks; editors such as VS Code run them as cells) or run
`%run display_render.py`: a Rendering is drawn as a cell's last value (its _repr_png_), and loomlight.display
draws anything image-like (a Rendering, PNG/WebP/JPEG/EXR bytes, a linear float array). As a script:

    python3 display_render.py [--preset velvet] [--scene sphere] [--out velvet.png] [--server HOST:PORT]

writes OUT (the render as the notebook shows it) and OUT with "-linear" before its extension (the same
material from float pixels, tone-mapped by loomlight.display).
"""
# %%
import argparse
import os
import sys

import loomlight

parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
parser.add_argument("--preset", default="velvet")
parser.add_argument("--scene", default="sphere")
parser.add_argument("--size", type=int, default=256)
parser.add_argument("--out", help="the PNG to write (default PRESET.png)")
parser.add_argument("--server", default=os.environ.get("LOOMLIGHT_SERVER", "127.0.0.1:50051"))
# parse_known_args: a notebook kernel's own arguments (-f kernel.json) are not ours.
args, _ = parser.parse_known_args(None if "ipykernel" not in sys.modules else [])
out = args.out or f"{args.preset}.png"
client = loomlight.Client(args.server, timeout=300)

# %%
# A render encoded by the server: the PNG bytes are what the notebook draws, untouched.
rendering = client.render(args.preset, args.scene, width=args.size, height=args.size, format="png",
                          background="white", lighting="studio")
rendering  # a cell's last value: Jupyter calls rendering._repr_png_() and draws it

# %%
# The same as a float32 linear array (format "array", read from the server's EXR; needs OpenImageIO's Python
# module), for pixel arithmetic. A transparent background gives a fourth channel, the coverage, which weighs each
# pixel in loomlight.display's exposure, so the empty frame does not; display tone-maps as the server does its
# 8-bit renders (that exposure, the ACES curve, sRGB), so it looks like the PNG above.
linear = client.render(args.preset, args.scene, width=args.size, height=args.size, format="array",
                       background="transparent", lighting="studio")
product = linear.image[..., 3] > 0.5
print(f"{linear.image.shape} {linear.image.dtype}, {product.mean():.0%} of the pixels on the product, mean "
      f"linear RGB there {tuple(linear.image[product, :3].mean(axis=0).round(4))}")
shown = loomlight.display(linear.image)  # drawn at once in a notebook (IPython.display); returned either way

# %%
# Outside a notebook there is nothing to draw on: write the PNGs a notebook would show.
if "ipykernel" not in sys.modules:
    stem, extension = os.path.splitext(out)
    with open(out, "wb") as f:
        f.write(rendering._repr_png_())
    with open(f"{stem}-linear{extension or '.png'}", "wb") as f:
        f.write(shown._repr_png_())
    print(f"wrote {out} and {stem}-linear{extension or '.png'} ({rendering.width} x {rendering.height})")
client.close()
