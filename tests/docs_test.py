#!/usr/bin/env python3
"""Runs every command in README.md and docs/*.md against a real loomlight-server, so the docs cannot go stale.

Conventions (docs/contributing.md, "Docs"):
- A fenced block opened with ```sh holds commands, one a line (a line ending in a backslash continues on the
  next; blank lines and lines starting with # are skipped). Every such block is run, unless the line just
  before its fence is `<!-- not run: REASON -->` (a reason is required). Other fences (```text, ```proto,
  ```csv, ...) are not run. A ```sh block without a command fails the test.
- Commands are written as run from the repository root: `build/...` (e.g. `build/loomlight`,
  `build/loomlight-server`, `build/bench/loomlight_bench`) becomes the build directory under test; each doc file's commands run in order, in a temporary directory of that file's own,
  which links the repository's read-only folders (deploy, docs, proto, tests, web) so paths like
  deploy/environments/sunset.exr resolve, and outputs land in the temporary directory. python/ is copied there
  instead (without build outputs), so that `pip install ./python` builds in the copy, not in the source tree.
- `python3` in a command is the interpreter of the Python package: $LOOMLIGHT_PYTHON, else Debian's
  /usr/bin/python3 where it exists (another python3 first on PATH, e.g. pyenv's, may lack grpc), else this one.
- One server serves every file (README.md first, then docs/ in name order), started on a free port with its
  own temporary data directory and the shipped environment maps; LOOMLIGHT_SERVER names it to the client.
- An image a doc shows, `![... (WxH)](path.png)`, must be a committed PNG that decodes to W x H pixels, and a
  command of the same doc must write a PNG of that file name and size (the picture's own command).
- Every relative link (`[text](docs/x.md#anchor)`, images too) names a file that exists and, for a Markdown file,
  a heading of it (GitHub's anchors: lower case, punctuation dropped, spaces as hyphens).
- Every path of the source tree a doc names (`server/...`, `tests/...`, `bench/report.md`, ...) exists, but for
  placeholders (a segment in capitals such as NAME, or a `*`/`{...}` pattern, which must match something).
- A command written as an indented code block (four spaces then build/, ./scripts/ or loomlight) fails the test:
  it would escape the run.

usage: docs_test.py --build-dir DIR --source-dir DIR [--only FILE...] [--keep] [--without-bench]
"""

import argparse
import glob
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zlib

NOT_RUN = re.compile(r"^\s*<!--\s*not run:\s*(\S.*?)\s*-->\s*$")
FENCE = re.compile(r"^(\s*)```\s*([A-Za-z0-9_+-]*)\s*$")
IMAGE = re.compile(r"!\[[^\]]*\((\d+)x(\d+)\)\]\(([^)\s]+\.png)\)")
INDENTED_COMMAND = re.compile(r"^    (build/|\./scripts/|scripts/|loomlight )")
BUILD_PATH = re.compile(r"(?<![\w./-])build/")
LINK = re.compile(r"\]\(([^)\s]+)\)")
INLINE_CODE = re.compile(r"`+[^`]*`+")
HEADING = re.compile(r"^#+ (.+)$", re.M)
SOURCE_PATH = re.compile(r"(?<![\w./$-])((?:bench|client|cmake|deploy|docs|kernels|proto|scripts|server|tests)/"
                         r"[\w./*{},-]*[\w*}/])")
LINKED_FOLDERS = ("deploy", "docs", "proto", "tests", "web")
COPIED_FOLDERS = ("python",)
COMMAND_TIMEOUT_S = 600


class Block:
    def __init__(self, path, line, language, skip_reason):
        self.path, self.line, self.language, self.skip_reason = path, line, language, skip_reason
        self.commands = []  # (line number, command)


def parse(path, text, problems):
    """The fenced blocks of one Markdown file, with their commands."""
    blocks = []
    lines = text.split("\n")
    block = None
    pending = None  # a command continued with a backslash: (line, text so far)
    for number, line in enumerate(lines, start=1):
        fence = FENCE.match(line)
        if block is None:
            if fence:
                previous = lines[number - 2] if number >= 2 else ""
                reason = NOT_RUN.match(previous)
                if "not run" in previous and not reason:
                    problems.append(f"{path}:{number - 1}: a not-run mark needs a reason: {previous.strip()}")
                block = Block(path, number, fence.group(2), reason.group(1) if reason else None)
                blocks.append(block)
            elif INDENTED_COMMAND.match(line):
                problems.append(f"{path}:{number}: a command in an indented code block (use a ```sh fence): "
                                f"{line.strip()}")
            continue
        if fence and not fence.group(2):
            if pending is not None:
                problems.append(f"{path}:{pending[0]}: the block ends inside a continued command")
                pending = None
            block = None
            continue
        if block.language != "sh":
            continue
        stripped = line.strip()
        if pending is None and (not stripped or stripped.startswith("#")):
            continue
        if pending is not None:
            text_so_far = pending[1] + " " + stripped
            start = pending[0]
        else:
            text_so_far, start = stripped, number
        if text_so_far.endswith("\\"):
            pending = (start, text_so_far[:-1].rstrip())
        else:
            pending = None
            block.commands.append((start, text_so_far))
    if block is not None:
        problems.append(f"{path}:{block.line}: a fenced block is never closed")
    return blocks


def anchor(heading):
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def prose_lines(text):
    """The lines outside fenced blocks, with inline code removed: where links are links."""
    inside = False
    for number, line in enumerate(text.split("\n"), start=1):
        if FENCE.match(line):
            inside = not inside
            continue
        if not inside:
            yield number, INLINE_CODE.sub("", line)


def check_links(root, name, text, problems):
    for number, line in prose_lines(text):
        for match in LINK.finditer(line):
            link = match.group(1)
            if re.match(r"^[a-z]+:", link):
                continue
            path, _, fragment = link.partition("#")
            target = os.path.normpath(os.path.join(root, os.path.dirname(name), path)) if path else \
                os.path.join(root, name)
            if not os.path.exists(target):
                problems.append(f"{name}:{number}: the link {link} names no file")
            elif fragment and target.endswith(".md"):
                with open(target, encoding="utf-8") as f:
                    headings = {anchor(h) for h in HEADING.findall(f.read())}
                if fragment not in headings:
                    problems.append(f"{name}:{number}: the link {link} names no heading of {path or name}")


def check_paths(root, name, text, problems):
    for number, line in enumerate(text.split("\n"), start=1):
        for match in SOURCE_PATH.finditer(line):
            path = match.group(1).rstrip("./")
            if any(segment.isupper() for segment in re.split(r"[/.]", path)):
                continue  # a placeholder: kernels/models/NAME.h
            if "*" in path or "{" in path:
                pattern = re.sub(r"\{[^}]*\}", "*", path)
                if not glob.glob(os.path.join(root, pattern)):
                    problems.append(f"{name}:{number}: nothing matches {path}")
            elif not os.path.exists(os.path.join(root, path)):
                problems.append(f"{name}:{number}: {path} does not exist")


def png_size(path):
    """(width, height) of a PNG whose pixel data decodes whole; raises ValueError otherwise."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG")
    offset, header, compressed = 8, None, b""
    while offset + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[offset:offset + 8])
        chunk = data[offset + 8:offset + 8 + length]
        if len(chunk) != length:
            raise ValueError("truncated chunk")
        if zlib.crc32(kind + chunk) != struct.unpack(">I", data[offset + 8 + length:offset + 12 + length])[0]:
            raise ValueError(f"bad CRC in {kind!r}")
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", chunk)
        elif kind == b"IDAT":
            compressed += chunk
        elif kind == b"IEND":
            break
        offset += 12 + length
    if header is None:
        raise ValueError("no IHDR")
    width, height, depth, colour, _, _, interlace = header
    channels = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}[colour]
    pixels = zlib.decompress(compressed)
    if interlace == 0:
        expected = height * (1 + (width * channels * depth + 7) // 8)
        if len(pixels) != expected:
            raise ValueError(f"{len(pixels)} bytes of pixel data, {expected} expected")
    return width, height


def start_server(server, client, root, work):
    log_path = os.path.join(work, "server.log")
    log = open(log_path, "w")
    process = subprocess.Popen(
        [server, "--address", "127.0.0.1:0", "--data-dir", os.path.join(work, "data"),
         "--environment-dir", os.path.join(root, "deploy", "environments")],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    port = None
    deadline = time.monotonic() + 300
    while port is None:
        if process.poll() is not None:
            sys.exit(f"FAIL: the server exited ({process.returncode}):\n" + open(log_path).read()[-3000:])
        if time.monotonic() > deadline:
            sys.exit("FAIL: the server did not report its port in 300 s")
        found = re.search(r"serving on port (\d+)", open(log_path).read())
        if found:
            port = int(found.group(1))
        else:
            time.sleep(0.1)
    target = f"127.0.0.1:{port}"
    while subprocess.run([client, "--server", target, "--timeout", "5", "health"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode != 0:
        if process.poll() is not None or time.monotonic() > deadline:
            sys.exit("FAIL: the server did not turn SERVING:\n" + open(log_path).read()[-3000:])
        time.sleep(0.5)
    return process, target


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--build-dir", required=True, help="the build tree: build/ in a command becomes it")
    parser.add_argument("--source-dir", required=True)
    parser.add_argument("--only", nargs="*", help="doc files to run (relative to the source dir)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary directory")
    parser.add_argument("--without-bench", action="store_true",
                        help="the build has no benchmark (LOOMLIGHT_BENCH=OFF): skip commands that run build/bench/")
    args = parser.parse_args()
    root = os.path.realpath(args.source_dir)
    build = os.path.realpath(args.build_dir)
    server, client = os.path.join(build, "loomlight-server"), os.path.join(build, "loomlight")

    docs_dir = os.path.join(root, "docs")
    files = ["README.md"] + sorted(os.path.join("docs", name) for name in os.listdir(docs_dir)
                                   if name.endswith(".md"))
    problems, blocks, pictures = [], [], []  # pictures: (doc, file name, width, height)
    for name in files:
        with open(os.path.join(root, name), encoding="utf-8") as f:
            text = f.read()
        blocks += parse(name, text, problems)
        check_links(root, name, text, problems)
        check_paths(root, name, text, problems)
        for match in IMAGE.finditer(text):
            width, height, image = int(match.group(1)), int(match.group(2)), match.group(3)
            pictures.append((name, os.path.basename(image), width, height))
            image_path = os.path.normpath(os.path.join(root, os.path.dirname(name), image))
            try:
                size = png_size(image_path)
                if size != (width, height):
                    problems.append(f"{name}: {image} is {size[0]}x{size[1]}, the doc says {width}x{height}")
            except (OSError, ValueError, KeyError, zlib.error) as error:
                problems.append(f"{name}: {image} does not decode: {error}")
    for block in blocks:
        if block.language == "sh" and not block.commands:
            problems.append(f"{block.path}:{block.line}: a ```sh block without a command")
    if problems:
        print("\n".join("FAIL: " + p for p in problems))
        return 1

    selected = [b for b in blocks if b.language == "sh" and (not args.only or b.path in args.only)]
    work = tempfile.mkdtemp(prefix="loomlight-docs-")
    started = time.monotonic()
    process, target = start_server(server, client, root, work)
    print(f"server at {target} ({time.monotonic() - started:.1f} s to SERVING)", flush=True)
    python = os.environ.get("LOOMLIGHT_PYTHON") or ("/usr/bin/python3" if os.path.exists("/usr/bin/python3")
                                                    else sys.executable)
    os.makedirs(os.path.join(work, "bin"))
    os.symlink(python, os.path.join(work, "bin", "python3"))
    environment = dict(os.environ, LOOMLIGHT_SERVER=target,
                       PATH=os.path.join(work, "bin") + os.pathsep + os.environ.get("PATH", ""))
    environment.pop("LOOMLIGHT_TOKEN", None)
    failures, ran, skipped = [], 0, []
    try:
        for block in selected:
            directory = os.path.join(work, block.path.replace("/", "_"))
            if not os.path.isdir(directory):
                os.makedirs(directory)
                for folder in LINKED_FOLDERS:
                    os.symlink(os.path.join(root, folder), os.path.join(directory, folder))
                for folder in COPIED_FOLDERS:
                    shutil.copytree(os.path.join(root, folder), os.path.join(directory, folder), symlinks=True,
                                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__", "v1"))
            for line, command in block.commands:
                where = f"{block.path}:{line}"
                if block.skip_reason is not None:
                    skipped.append((where, command, block.skip_reason))
                    continue
                if args.without_bench and "build/bench/" in command:
                    skipped.append((where, command, "built without the benchmark (LOOMLIGHT_BENCH=OFF)"))
                    continue
                run = BUILD_PATH.sub(lambda m: build + "/", command)
                began = time.monotonic()
                try:
                    result = subprocess.run(["bash", "-o", "pipefail", "-c", run], cwd=directory, env=environment,
                                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                            timeout=COMMAND_TIMEOUT_S, text=True, errors="replace")
                    status, output = result.returncode, result.stdout
                except subprocess.TimeoutExpired as expired:
                    status, output = f"timed out after {COMMAND_TIMEOUT_S} s", str(expired.output or "")
                ran += 1
                seconds = time.monotonic() - began
                if status == 0:
                    print(f"ok   {where} ({seconds:.1f} s): {command}", flush=True)
                else:
                    print(f"FAIL {where} (exit {status}): {command}\n{output[-2000:]}", flush=True)
                    failures.append(f"{where}: {command} (exit {status})")
        # Each picture's command ran: its output has the committed picture's size.
        for doc, image, width, height in pictures:
            if args.only and doc not in args.only:
                continue
            made = os.path.join(work, doc.replace("/", "_"), image)
            try:
                size = png_size(made)
                if size != (width, height):
                    failures.append(f"{doc}: the command writing {image} made {size[0]}x{size[1]}, the doc shows "
                                    f"{width}x{height}")
            except (OSError, ValueError, KeyError, zlib.error) as error:
                failures.append(f"{doc}: no command of the doc wrote {image} as a PNG ({error})")
    finally:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
        if failures or args.keep:
            print(f"files kept in {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)

    for where, command, reason in skipped:
        print(f"skip {where}: {command} ({reason})")
    print(f"docs_test: {ran} commands run, {len(skipped)} skipped, {len(failures)} failed, "
          f"{time.monotonic() - started:.0f} s")
    for failure in failures:
        print("FAIL: " + failure)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
