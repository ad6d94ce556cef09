#!/usr/bin/env python3
"""Writes the binary and generated test fixtures of scene_loader_test.

Run once from this folder (python3 standard library only); the outputs are
committed, so the tests do not need Python:

  checker_2x2.png          2x2 sRGB texture: top row red, green; bottom row blue, grey 128
  two_materials.gltf       glTF 2.0, buffer and texture embedded as base64 data URIs
  two_materials.glb        the same scene as a binary glTF (buffer and PNG in the BIN chunk)

The glTF scene, in its node hierarchy:
  root (translation 0 1 0)
    quad  (scale 2): unit square in z = 0, facing +z, material "textured":
                     baseColorFactor (0.5, 1, 1) x checker_2x2.png
    lamp  (translation 0 0 -1): one triangle in z = 0, facing +z, material "lamp":
                     baseColorFactor 0, emissiveFactor (1, 0.5, 0.25),
                     KHR_materials_emissive_strength 4
"""
import base64
import json
import struct
import zlib


def png_rgb8(rows):
    """A PNG file (bytes) from rows of (r, g, b) tuples, top row first."""
    height, width = len(rows), len(rows[0])
    raw = b"".join(b"\x00" + bytes(c for pixel in row for c in pixel) for row in rows)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


CHECKER = png_rgb8([[(255, 0, 0), (0, 255, 0)], [(0, 0, 255), (128, 128, 128)]])


def geometry_buffer():
    """Vertex and index data of both meshes, and the bufferViews/accessors over it."""
    quad_positions = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    # glTF texture coordinates start at the image's top-left corner.
    quad_uvs = [(0, 1), (1, 1), (1, 0), (0, 0)]
    quad_indices = [0, 1, 2, 0, 2, 3]
    lamp_positions = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    lamp_indices = [0, 1, 2, 0]  # one triangle, padded to 4-byte alignment

    blobs = [
        b"".join(struct.pack("<3f", *p) for p in quad_positions),
        b"".join(struct.pack("<2f", *t) for t in quad_uvs),
        struct.pack("<6H", *quad_indices),
        b"".join(struct.pack("<3f", *p) for p in lamp_positions),
        struct.pack("<4H", *lamp_indices),
    ]
    views, offset = [], 0
    for blob in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(blob)})
        offset += len(blob) + (-len(blob) % 4)
    data = b"".join(blob + b"\x00" * (-len(blob) % 4) for blob in blobs)
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
        {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
        {"bufferView": 3, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
        {"bufferView": 4, "componentType": 5123, "count": 3, "type": "SCALAR"},
    ]
    return data, views, accessors


def document(image):
    return {
        "asset": {"version": "2.0", "generator": "penumbra make_fixtures.py"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {"name": "root", "translation": [0, 1, 0], "children": [1, 2]},
            {"name": "quad", "scale": [2, 2, 2], "mesh": 0},
            {"name": "lamp", "translation": [0, 0, -1], "mesh": 1},
        ],
        "meshes": [
            {"name": "quad", "primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]},
            {"name": "lamp", "primitives": [{"attributes": {"POSITION": 3}, "indices": 4, "material": 1}]},
        ],
        "materials": [
            {"name": "textured",
             "pbrMetallicRoughness": {"baseColorFactor": [0.5, 1, 1, 1], "baseColorTexture": {"index": 0},
                                      "metallicFactor": 0}},
            {"name": "lamp",
             "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0},
             "emissiveFactor": [1, 0.5, 0.25],
             "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4}}},
        ],
        "samplers": [{"magFilter": 9729, "minFilter": 9729}],
        "textures": [{"source": 0, "sampler": 0}],
        "images": [image],
    }


def write_gltf():
    data, views, accessors = geometry_buffer()
    doc = document({"uri": "data:image/png;base64," + base64.b64encode(CHECKER).decode()})
    doc["buffers"] = [{"byteLength": len(data),
                       "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}]
    doc["bufferViews"], doc["accessors"] = views, accessors
    with open("two_materials.gltf", "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")


def write_glb():
    data, views, accessors = geometry_buffer()
    image_view = {"buffer": 0, "byteOffset": len(data), "byteLength": len(CHECKER)}
    data += CHECKER + b"\x00" * (-len(CHECKER) % 4)
    doc = document({"bufferView": len(views), "mimeType": "image/png"})
    doc["buffers"] = [{"byteLength": len(data)}]
    doc["bufferViews"], doc["accessors"] = views + [image_view], accessors
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(data), b"BIN\x00") + data
    with open("two_materials.glb", "wb") as f:
        f.write(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)


if __name__ == "__main__":
    with open("checker_2x2.png", "wb") as f:
        f.write(CHECKER)
    write_gltf()
    write_glb()
