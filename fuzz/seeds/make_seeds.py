#!/usr/bin/env python3
"""Writes the binary seeds of fuzz/seeds/ that no file of data/ or tests/ provides: tiny frame
files (PNG 8/16-bit gray, RGB, RGBA, raw YUYV and NV12 as GRAY8; JPEG through GStreamer's jpegenc),
a GLB quad, a glTF quad with an embedded PNG texture and a response table. Small on purpose: the
fuzzer mutates them thousands of times a second. Run from anywhere; rerun to regenerate."""
import base64, json, os, struct, subprocess, zlib

here = os.path.dirname(os.path.abspath(__file__))


def out(harness, name, data):
    os.makedirs(os.path.join(here, harness), exist_ok=True)
    with open(os.path.join(here, harness, name), "wb") as f:
        f.write(data)


def png(width, height, colour_type, bit_depth, channels):
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)
    bytes_per_sample = bit_depth // 8
    rows = b""
    for y in range(height):
        row = bytes(((x * 37 + y * 11 + c * 5) & 0xFF) for x in range(width) for c in range(channels * bytes_per_sample))
        rows += b"\x00" + row
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")


out("frame_file", "gray8.png", png(8, 8, 0, 8, 1))
out("frame_file", "gray16.png", png(8, 8, 0, 16, 1))
out("frame_file", "rgb8.png", png(8, 8, 2, 8, 3))
out("frame_file", "rgba8.png", png(8, 8, 6, 8, 4))
out("frame_file", "yuyv_as_gray8.png", png(16, 8, 0, 8, 1))  # 8x8 YUYV: 2*width columns
out("frame_file", "nv12_as_gray8.png", png(8, 12, 0, 8, 1))  # 8x8 NV12: height*3/2 rows
jpeg = os.path.join(here, "frame_file", "rgb.jpg")
subprocess.run(["gst-launch-1.0", "-q", "videotestsrc", "num-buffers=1", "!", "video/x-raw,width=16,height=16", "!",
                "jpegenc", "!", "filesink", "location=" + jpeg], check=True)

# A unit quad: 4 positions, 4 normals, 6 indices (two triangles), as in tests/core/data/quad.gltf.
positions = [0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0]
normals = [0, 0, 1] * 4
texcoords = [0, 1, 1, 1, 1, 0, 0, 0]
indices = [0, 1, 2, 0, 2, 3]
buffer = struct.pack("<12f", *positions) + struct.pack("<12f", *normals) + struct.pack("<6H", *indices) + b"\0\0"
buffer += b"\0" * (-len(buffer) % 4)  # GLB's BIN chunk ends on a 4-byte boundary
buffer_tex = buffer + struct.pack("<8f", *texcoords)


def gltf(buffer_entry, textured):
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "rotation": [0, 0, 0.7071068, 0.7071068], "scale": [1, 2, 1]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "mode": 4}]}],
        "buffers": [buffer_entry],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 48},
                        {"buffer": 0, "byteOffset": 96, "byteLength": 12}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
                      {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
                      {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}],
    }
    if textured:
        doc["bufferViews"].append({"buffer": 0, "byteOffset": 108, "byteLength": 32})
        doc["accessors"].append({"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC2"})
        doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 3
        doc["meshes"][0]["primitives"][0]["material"] = 0
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [1, 0.5, 0.25, 1],
                                                      "baseColorTexture": {"index": 0}}}]
        doc["textures"] = [{"source": 0, "sampler": 0}]
        doc["samplers"] = [{"wrapS": 33071, "wrapT": 10497}]
        doc["images"] = [{"uri": "data:image/png;base64," + base64.b64encode(png(2, 2, 2, 8, 3)).decode()}]
    return doc


textured = gltf({"byteLength": len(buffer_tex),
                 "uri": "data:application/octet-stream;base64," + base64.b64encode(buffer_tex).decode()}, True)
out("gltf", "textured_quad.gltf", json.dumps(textured, indent=1).encode())

doc = json.dumps(gltf({"byteLength": len(buffer)}, False), separators=(",", ":")).encode()
doc += b" " * (-len(doc) % 4)
glb_body = struct.pack("<II", len(doc), 0x4E4F534A) + doc + struct.pack("<II", len(buffer), 0x004E4942) + buffer
out("glb", "quad.glb", struct.pack("<III", 0x46546C67, 2, 12 + len(glb_body)) + glb_body)

table = ", ".join("%.6g" % ((c / 255.0) ** 2.2) for c in range(256))
out("response", "gamma22.yaml",
    ("response:\n  type: table\n  method: debevec\n  r: [%s]\n  g: [%s]\n  b: [%s]\n" % (table, table, table)).encode())
