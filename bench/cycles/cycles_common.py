# What the Cycles scripts of the benchmarks share (bench/cycles/cylinders.py, product.py): an equirectangular map as
# the world, Cycles set up to render as Loomlight shades (CPU, direct light only, no denoiser, no adaptive sampling,
# a 1-pixel box filter, 32-bit EXR), timed renders, and the run over a list of NAME:SPP:SEED:RUNS renders writing
# DIR/NAME.exr, DIR/times.tsv ("NAME SPP SEED SECONDS", the fastest run's time in bpy's render operator: scene sync,
# BVH, world map and sampling; not Blender's start-up nor the file write) and DIR/version.txt.
import os
import sys
import time

import bpy


def set_world_map(scene, path, name):
    """The map as the world, looked up per texel as the server does (closest, no filtering), importance sampled
    at its own resolution."""
    world = bpy.data.worlds.new(name)
    world.use_nodes = True
    nodes = world.node_tree.nodes
    texture = nodes.new("ShaderNodeTexEnvironment")
    texture.image = bpy.data.images.load(path)
    texture.interpolation = "Closest"
    texture.projection = "EQUIRECTANGULAR"
    world.node_tree.links.new(texture.outputs["Color"], nodes["Background"].inputs["Color"])
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = texture.image.size[0]
    scene.world = world


def configure_cycles(scene, threads, size, color_mode, transparent=False):
    scene.render.engine = "CYCLES"
    scene.render.film_transparent = transparent
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.use_adaptive_sampling = False
    cycles.use_denoising = False  # Debian's Blender has no OpenImageDenoise
    cycles.time_limit = 0
    cycles.use_animated_seed = False
    cycles.pixel_filter_type = "BOX"  # Loomlight's jittered pixel samples
    cycles.filter_width = 1.0
    # Direct light only: Loomlight shades the camera ray's hit by the lights and the map, nothing bounced.
    cycles.max_bounces = 0
    for bounces in ("diffuse_bounces", "glossy_bounces", "transmission_bounces", "volume_bounces",
                    "transparent_max_bounces"):
        setattr(cycles, bounces, 0)
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_mode = color_mode
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"


def render(scene, samples, seed):
    scene.cycles.samples = samples
    scene.cycles.seed = seed
    start = time.perf_counter()
    bpy.ops.render.render()
    return time.perf_counter() - start


def run_renders(scene, out, renders):
    """Each NAME:SPP:SEED:RUNS of `renders` (comma-separated) RUNS times, after one untimed 1-sample warm-up."""
    with open(os.path.join(out, "version.txt"), "w") as version:
        version.write(bpy.app.version_string + "\n")
    render(scene, 1, 0)  # warm-up
    with open(os.path.join(out, "times.tsv"), "w") as times:
        for job in renders.split(","):
            name, samples, seed, runs = job.split(":")
            seconds = min(render(scene, int(samples), int(seed)) for _ in range(int(runs)))
            bpy.data.images["Render Result"].save_render(os.path.join(out, name + ".exr"))
            times.write(f"{name}\t{samples}\t{seed}\t{seconds:.6f}\n")
            times.flush()
            print(f"cycles: {name}, {samples} samples per pixel, seed {seed}: {seconds:.3f} s", file=sys.stderr)
