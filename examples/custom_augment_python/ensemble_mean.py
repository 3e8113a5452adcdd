#!/usr/bin/env python3
"""EnsembleMean in Python: a custom augmentation for augsplat, run by the engine's `Command` node.

The Python twin of the Rust `EnsembleMean` node (examples/custom_augment/src/lib.rs), using numpy
and the standard library only. It reads the render folders of the radiance-field ensemble's
members (RenderField outputs: `renders.json` listing views with `name`, `camera`, `file`, and one
EXR per view with channels R, G, B, D, A) and writes a synthetic set, contract version 1 (see
"Custom augmentation: the synthetic-set contract" in the README), into the output folder:

    synthetic.json      {"views": [{"name", "camera", "target", "weight", "weight_sum"}]}
    targets/<stem>.exr  float R, G, B: the per-pixel mean of the members' colours
    weights/<stem>.exr  float W: clamp(mean of the members' opacity A, 0, 1) ** power

Members are summed in member order in float32, then divided by their count, exactly as the Rust
node does, so both write the same values. Usage (pipelines/custom_augment_python.ron):

    python3 ensemble_mean.py [--power P] --out OUT_DIR MEMBER_DIR [MEMBER_DIR ...]

Errors (a missing or unreadable file, members that disagree on their views or sizes, an EXR
this reader does not support) go to stderr, naming the file, with exit status 1.
"""

import argparse
import json
import math
import struct
import sys
import zlib
from pathlib import Path

import numpy as np

CONTRACT_VERSION = 1  # the synthetic-set folder layout written here


class Failure(Exception):
    """An error whose message names the file it concerns."""


def fail(path, what):
    raise Failure(f"{path}: {what}")


# ---------------------------------------------------------------------------------------------
# OpenEXR: a reader for single-part scanline images (NONE, ZIPS, ZIP; HALF, FLOAT) and a
# writer of uncompressed FLOAT scanline images.

EXR_MAGIC = b"\x76\x2f\x31\x01"
COMPRESSIONS = ["NONE", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "B44A", "DWAA", "DWAB"]
LINES_PER_BLOCK = {"NONE": 1, "ZIPS": 1, "ZIP": 16}  # the compressions this reader supports
PIXEL_TYPES = {1: np.dtype("<f2"), 2: np.dtype("<f4")}  # HALF, FLOAT (0 = UINT: unsupported)


def _cstring(data, pos, path):
    end = data.find(b"\0", pos)
    if end < 0:
        fail(path, "truncated EXR header")
    return data[pos:end].decode("latin-1"), end + 1


def _channel_list(raw, path):
    """The `chlist` attribute: [(name, dtype)] in file order (alphabetical)."""
    channels, pos = [], 0
    while pos < len(raw) and raw[pos] != 0:
        name, pos = _cstring(raw, pos, path)
        if pos + 16 > len(raw):
            fail(path, "truncated channel list")
        ptype, _linear, xs, ys = struct.unpack_from("<iB3xii", raw, pos)
        pos += 16
        if ptype not in PIXEL_TYPES:
            kind = {0: "UINT"}.get(ptype, f"type {ptype}")
            fail(path, f"channel {name} has pixel type {kind}; only HALF and FLOAT are supported")
        if (xs, ys) != (1, 1):
            fail(path, f"channel {name} is subsampled ({xs}, {ys}), which is not supported")
        channels.append((name, PIXEL_TYPES[ptype]))
    return channels


def _unzip(block, expected, path, y):
    """Undoes ZIP(S) compression: inflate, undo the delta predictor, re-interleave the halves."""
    try:
        raw = np.frombuffer(zlib.decompress(block), dtype=np.uint8)
    except zlib.error as e:
        fail(path, f"corrupt ZIP data in the block at line {y}: {e}")
    if raw.size != expected:
        fail(path, f"the block at line {y} inflates to {raw.size} bytes, expected {expected}")
    deltas = raw.astype(np.int64)
    deltas[1:] -= 128
    predicted = (np.cumsum(deltas) & 0xFF).astype(np.uint8)
    half = (expected + 1) // 2
    out = np.empty(expected, dtype=np.uint8)
    out[0::2] = predicted[:half]
    out[1::2] = predicted[half:]
    return out


def read_exr(path):
    """Reads every channel of a scanline EXR: (width, height, {name: float32 array H×W})."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        fail(path, f"cannot read: {e.strerror}")
    if len(data) < 8 or data[:4] != EXR_MAGIC:
        fail(path, "not an OpenEXR file")
    (flags,) = struct.unpack_from("<I", data, 4)
    for bit, what in [(0x200, "tiled images"), (0x800, "deep data"), (0x1000, "multi-part files")]:
        if flags & bit:
            fail(path, f"{what} are not supported (only single-part scanline images)")
    attrs, pos = {}, 8
    while pos < len(data) and data[pos] != 0:
        name, pos = _cstring(data, pos, path)
        _type, pos = _cstring(data, pos, path)
        if pos + 4 > len(data):
            fail(path, "truncated EXR header")
        (size,) = struct.unpack_from("<i", data, pos)
        attrs[name] = data[pos + 4 : pos + 4 + size]
        pos += 4 + size
    pos += 1  # the header's terminating zero byte
    for required in ["channels", "compression", "dataWindow"]:
        if required not in attrs:
            fail(path, f"the EXR header has no `{required}` attribute")
    code = attrs["compression"][0]
    compression = COMPRESSIONS[code] if code < len(COMPRESSIONS) else f"code {code}"
    if compression not in LINES_PER_BLOCK:
        fail(path, f"compression {compression} is not supported (only NONE, ZIPS and ZIP)")
    channels = _channel_list(attrs["channels"], path)
    xmin, ymin, xmax, ymax = struct.unpack("<iiii", attrs["dataWindow"])
    width, height = xmax - xmin + 1, ymax - ymin + 1
    lines = LINES_PER_BLOCK[compression]
    chunks = -(-height // lines)
    if pos + 8 * chunks > len(data):
        fail(path, "truncated offset table")
    offsets = struct.unpack_from(f"<{chunks}Q", data, pos)
    line_bytes = width * sum(dt.itemsize for _, dt in channels)
    planes = {name: np.zeros((height, width), dtype=np.float32) for name, _ in channels}
    seen = np.zeros(height, dtype=bool)
    for offset in offsets:
        if offset + 8 > len(data):
            fail(path, f"a block offset ({offset}) lies past the end of the file")
        y, size = struct.unpack_from("<ii", data, offset)
        row = y - ymin
        if row < 0 or row >= height or row % lines:
            fail(path, f"a block starts at line {y}, outside the data window or off its grid")
        if size < 0 or offset + 8 + size > len(data):
            fail(path, f"the file is truncated: the block at line {y} ends past its end")
        n = min(lines, height - row)
        block = data[offset + 8 : offset + 8 + size]
        if size == n * line_bytes:  # stored raw (compression would not have made it smaller)
            pixels = np.frombuffer(block, dtype=np.uint8)
        elif compression == "NONE":
            fail(path, f"the block at line {y} holds {size} bytes, expected {n * line_bytes}")
        else:
            pixels = _unzip(block, n * line_bytes, path, y)
        seen[row : row + n] = True
        pixels = pixels.reshape(n, line_bytes)
        col = 0
        for name, dt in channels:  # per scanline, each channel's samples in turn
            span = width * dt.itemsize
            values = np.ascontiguousarray(pixels[:, col : col + span]).view(dt)
            planes[name][row : row + n] = values.astype(np.float32)
            col += span
    if not seen.all():
        fail(path, f"line {ymin + int(np.argmin(seen))} is in no block of the file")
    return width, height, planes


def write_exr(path, width, height, planes):
    """Writes {name: float32 H×W} as an uncompressed (NONE) FLOAT scanline EXR."""
    names = sorted(planes)  # OpenEXR stores channels in alphabetical order

    def attr(name, kind, value):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    # Per channel: name, pixel type 2 (FLOAT), pLinear 0, 3 reserved bytes, sampling (1, 1).
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for n in names)
    chlist += b"\0"
    window = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = EXR_MAGIC + struct.pack("<I", 2) + b"".join([
        attr("channels", "chlist", chlist),
        attr("compression", "compression", b"\0"),
        attr("dataWindow", "box2i", window),
        attr("displayWindow", "box2i", window),
        attr("lineOrder", "lineOrder", b"\0"),
        attr("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0)),
        attr("screenWindowWidth", "float", struct.pack("<f", 1.0)),
    ]) + b"\0"
    # Scanline y holds each channel's row in turn: (height, channels, width) little-endian f32.
    rows = np.stack([np.asarray(planes[n], dtype="<f4").reshape(height, width) for n in names], 1)
    line_bytes = len(names) * width * 4
    first = len(header) + 8 * height
    offsets = struct.pack(f"<{height}Q", *(first + y * (8 + line_bytes) for y in range(height)))
    blocks = b"".join(struct.pack("<ii", y, line_bytes) + rows[y].tobytes() for y in range(height))
    Path(path).write_bytes(header + offsets + blocks)


# ---------------------------------------------------------------------------------------------
# The synthetic set.


def file_stem(name):
    """augsplat_core::artifacts::file_stem: keeps ASCII letters, digits, `-`, `_`, `.`."""
    return "".join(c if (c.isascii() and c.isalnum()) or c in "-_." else "_" for c in name)


def read_members(dirs):
    """Each member's `renders.json` views, checked to list the same views at the same sizes."""
    sets = []
    for d in dirs:
        index = Path(d) / "renders.json"
        try:
            views = json.loads(index.read_text())["views"]
            complete = all({"name", "camera", "file"} <= v.keys()
                           and {"width", "height"} <= v["camera"].keys() for v in views)
        except OSError as e:
            fail(index, f"cannot read: {e.strerror}")
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            fail(index, f"not a render set ({type(e).__name__}: {e})")
        if not complete:
            fail(index, "a view lacks its name, file, or camera width and height")
        sets.append(views)

    def size(view):
        return view["camera"]["width"], view["camera"]["height"]

    for k, views in enumerate(sets[1:], 1):
        index = Path(dirs[k]) / "renders.json"
        if len(views) != len(sets[0]):
            fail(index, f"member {k} has {len(views)} views, "
                        f"member 0 ({dirs[0]}) has {len(sets[0])}")
        for a, b in zip(sets[0], views):
            if a["name"] != b["name"] or size(a) != size(b):
                fail(index, "member {} view `{}` ({}×{}) does not match member 0 view `{}` "
                     "({}×{})".format(k, b["name"], *size(b), a["name"], *size(a)))
    return sets


def read_render(path, width, height):
    """One member's render of a view: RGB (3, H, W) and opacity A (H, W), float32, finite."""
    w, h, planes = read_exr(path)
    if (w, h) != (width, height):
        fail(path, f"image is {w}×{h}, its camera says {width}×{height}")
    for ch in "RGBA":
        if ch not in planes:
            fail(path, f"no channel {ch} (has {sorted(planes)})")
        bad = np.argwhere(~np.isfinite(planes[ch]))
        if len(bad):
            fail(path, f"channel {ch} holds a non-finite value at pixel ({bad[0][1]}, {bad[0][0]})")
    return np.stack([planes["R"], planes["G"], planes["B"]]), planes["A"]


def ensemble_mean(dirs, out, power):
    """Writes the synthetic set of the members' mean into `out`; returns its view count."""
    sets = read_members(dirs)
    out = Path(out)
    for sub in ["targets", "weights"]:
        (out / sub).mkdir(parents=True, exist_ok=True)
    k, entries, stems = np.float32(len(dirs)), [], set()
    for vi, view in enumerate(sets[0]):
        cam = view["camera"]
        w, h = cam["width"], cam["height"]
        rgb_sum = np.zeros((3, h, w), dtype=np.float32)
        alpha_sum = np.zeros((h, w), dtype=np.float32)
        for d, views in zip(dirs, sets):  # member order, float32: as the Rust node sums
            rgb, alpha = read_render(Path(d) / views[vi]["file"], w, h)
            rgb_sum += rgb
            alpha_sum += alpha
        target = rgb_sum / k
        weight = np.power(np.clip(alpha_sum / k, np.float32(0), np.float32(1)), np.float32(power))
        stem = file_stem(view["name"])
        if stem in stems:
            fail(out / "synthetic.json", f"two views share the file stem `{stem}`")
        stems.add(stem)
        entry = {"name": view["name"], "camera": cam,
                 "target": f"targets/{stem}.exr", "weight": f"weights/{stem}.exr"}
        write_exr(out / entry["target"], w, h, {"R": target[0], "G": target[1], "B": target[2]})
        write_exr(out / entry["weight"], w, h, {"W": weight})
        # The sum in float64 in pixel order, as SyntheticView::write computes it.
        flat = weight.astype(np.float64).ravel()
        entry["weight_sum"] = float(np.cumsum(flat)[-1]) if flat.size else 0.0
        entries.append(entry)
    (out / "synthetic.json").write_text(json.dumps({"views": entries}, indent=2))
    return len(entries)


def main(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--power", type=float, default=1.0,
                   help="confidence = mean opacity ** power (>= 0; default 1)")
    p.add_argument("--out", required=True, help="the synthetic set's folder (created)")
    p.add_argument("members", nargs="+", help="the members' render folders (renders.json)")
    args = p.parse_args(argv)
    if not (math.isfinite(args.power) and args.power >= 0):
        p.error(f"--power {args.power} must be finite and >= 0")
    try:
        n = ensemble_mean(args.members, args.out, args.power)
    except Failure as e:
        print(f"ensemble_mean.py: error: {e}", file=sys.stderr)
        return 1
    print(f"ensemble mean of {len(args.members)} members over {n} views "
          f"(confidence: mean opacity^{args.power}); synthetic set version {CONTRACT_VERSION}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
