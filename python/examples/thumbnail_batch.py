#!/usr/bin/env python3
"""Renders a catalogue of thumbnails: one image per product and colourway, listed in a CSV.

    python3 thumbnail_batch.py catalogue.csv --out thumbnails [--server HOST:PORT] [--format webp]

The CSV (catalogue.csv beside this script is an example) has a header and these columns:

    product        a name for the file (letters, digits, - and _)
    colourway      a name for the file, too: the image is OUT/PRODUCT_COLOURWAY.png (or .webp)
    preset         a material preset (`loomlight models` lists them)
    scene_or_mesh  a scene (`loomlight scenes`: sphere, drape_stand, ...), or a glTF/OBJ file (.glb, .gltf,
                   .obj; relative to the CSV) whose every panel wears the material
    params         optional overrides of the preset: NAME=V1 V2 V3, separated by ';'
                   (thread1.albedo=0.05 0.30 0.10; thread2.albedo=0.30 0.05 0.05)
    lighting       optional: a lighting preset, studio (the default), studio_high_key or softbox_top

A few renders run at once on one shared Client (a gRPC channel is thread-safe). A render refused for a
moment (UNAVAILABLE: the server restarting or unreachable; RESOURCE_EXHAUSTED: its queue full) is retried after
a growing pause; any other error is the row's and is reported, not retried. Images that already exist are
skipped, so a rerun after an interruption renders only what is missing. OUT/summary.csv lists every job with
its worst estimated fidelity error, its error message if it failed, and its seconds.
"""
import argparse
import concurrent.futures
import csv
import os
import pathlib
import random
import re
import sys
import time

import loomlight

SUMMARY_COLUMNS = ["product", "colourway", "file", "status", "fidelity", "error", "seconds", "attempts"]
MESH_SUFFIXES = (".glb", ".gltf", ".obj")
# The calls worth another try: the server (or the way to it) is busy or gone for a moment.
RETRIED = (loomlight.UnavailableError, loomlight.ResourceExhaustedError)


def parse_params(text, where):
    """'thread1.albedo=0.05 0.3 0.1; thread1.kd=0.4' as {"thread1.albedo": [0.05, 0.3, 0.1], "thread1.kd": 0.4}."""
    params = {}
    for item in filter(None, (part.strip() for part in (text or "").split(";"))):
        name, equals, values = item.partition("=")
        if not equals:
            raise ValueError(f"{where}: '{item}' is not NAME=VALUES")
        try:
            numbers = [float(v) for v in values.replace(",", " ").split()]
        except ValueError:
            raise ValueError(f"{where}: {name.strip()}: '{values.strip()}' are not numbers") from None
        params[name.strip()] = numbers[0] if len(numbers) == 1 else numbers
    return params


def read_jobs(path):
    jobs = []
    with open(path, newline="", encoding="utf-8") as f:
        for line, row in enumerate(csv.DictReader(f), start=2):
            where = f"{path}:{line}"
            missing = [c for c in ("product", "colourway", "preset", "scene_or_mesh") if not (row.get(c) or "").strip()]
            if missing:
                raise ValueError(f"{where}: no {', '.join(missing)}")
            job = {key: (value or "").strip() for key, value in row.items() if key}
            # The names become a file name: keep them to characters every file system takes.
            for key in ("product", "colourway"):
                if not re.fullmatch(r"[A-Za-z0-9_-]+", job[key]):
                    raise ValueError(f"{where}: {key} '{job[key]}': letters, digits, '-' and '_' only")
            job["params"] = parse_params(job.get("params"), where)
            if job["scene_or_mesh"].lower().endswith(MESH_SUFFIXES):
                job["scene_or_mesh"] = os.path.join(os.path.dirname(os.path.abspath(path)), job["scene_or_mesh"])
            job["where"] = where
            jobs.append(job)
    return jobs


def read_summary(path):
    """The previous run's summary rows by file name (none on a first run)."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            return {row["file"]: row for row in csv.DictReader(f)}
    except (OSError, KeyError):
        return {}


def render_one(client, job, args, previous):
    """Renders one job (retrying what may pass later) and writes its image; returns its summary row."""
    output = os.path.join(args.out, f"{job['product']}_{job['colourway']}.{args.format}")
    row = {"product": job["product"], "colourway": job["colourway"], "file": os.path.basename(output),
           "status": "", "fidelity": "", "error": "", "seconds": "", "attempts": 0}
    if os.path.exists(output):
        # Done by an earlier run: keep what that run measured.
        earlier = previous.get(row["file"], {})
        row.update(status="skipped", fidelity=earlier.get("fidelity", ""), seconds=earlier.get("seconds", ""))
        return row
    began = time.monotonic()
    scene_or_mesh = job["scene_or_mesh"]
    # A str is a scene's (or a stored mesh's) name; a path object is a file sent with the request.
    mesh = pathlib.Path(scene_or_mesh) if scene_or_mesh.lower().endswith(MESH_SUFFIXES) else None

    def render():
        # client.material checks the overrides against the server's schema (fetched once, by the first job)
        # before anything is rendered: a typo in the CSV fails its own row, naming the parameter.
        material = client.material(job["preset"], params=job["params"])
        return client.render(material, None if mesh else scene_or_mesh, mesh=mesh, width=args.size,
                             height=args.size, format=args.format, background="white",
                             lighting=job.get("lighting") or "studio")

    try:
        for attempt in range(args.retries + 1):
            row["attempts"] = attempt + 1
            try:
                rendering = render()
                break
            except RETRIED:
                if attempt == args.retries:
                    raise
                # Exponential backoff with jitter, so that workers refused together do not come back together.
                time.sleep(args.backoff * 2 ** attempt * (0.5 + random.random()))
    except (loomlight.LoomlightError, OSError) as error:
        row.update(status="failed", error=str(error), seconds=f"{time.monotonic() - began:.2f}")
        return row
    # Written under a temporary name and renamed: an interrupted run leaves no half image that a rerun would skip.
    with open(output + ".part", "wb") as f:
        f.write(rendering.image)
    os.replace(output + ".part", output)
    # The fidelity report gives each object's estimated error (relative L1 against the full model): the worst one.
    worst = max((obj.get("estimated_error", 0.0) for obj in rendering.fidelity), default=0.0)
    row.update(status="rendered", fidelity=f"{worst:.4f}", seconds=f"{time.monotonic() - began:.2f}")
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("catalogue", help="the CSV of jobs")
    parser.add_argument("--out", default="thumbnails", help="the folder of images and summary.csv")
    parser.add_argument("--server", default=os.environ.get("LOOMLIGHT_SERVER", "127.0.0.1:50051"))
    parser.add_argument("--format", choices=("png", "webp"), default="png")
    parser.add_argument("--size", type=int, default=256, help="width and height in pixels")
    parser.add_argument("--workers", type=int, default=3, help="renders in flight at once")
    parser.add_argument("--retries", type=int, default=4, help="tries after the first for UNAVAILABLE and "
                                                                 "RESOURCE_EXHAUSTED")
    parser.add_argument("--backoff", type=float, default=1.0, help="seconds before the first retry (then doubled)")
    parser.add_argument("--timeout", type=float, default=300, help="each render's deadline in seconds")
    args = parser.parse_args()

    try:
        jobs = read_jobs(args.catalogue)
    except (OSError, ValueError) as error:
        sys.exit(f"thumbnail_batch: {error}")
    os.makedirs(args.out, exist_ok=True)
    summary_path = os.path.join(args.out, "summary.csv")
    previous = read_summary(summary_path)
    rows = []
    with loomlight.Client(args.server, timeout=args.timeout) as client:
        with concurrent.futures.ThreadPoolExecutor(max_workers=args.workers) as pool:
            futures = [pool.submit(render_one, client, job, args, previous) for job in jobs]
            for job, future in zip(jobs, futures):
                row = future.result()
                rows.append(row)
                detail = row["error"] or (f"fidelity {row['fidelity']}, {row['seconds']} s"
                                          if row["status"] == "rendered" else "")
                print(f"{row['status']:8} {row['file']}" + (f": {detail}" if detail else ""), flush=True)

    with open(summary_path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    failed = sum(row["status"] == "failed" for row in rows)
    print(f"{len(rows) - failed} of {len(rows)} thumbnails in {args.out} ({failed} failed); summary in "
          f"{summary_path}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
