#!/usr/bin/env python3
"""Writes inverted_room.obj/.mtl: geometry as real models have it.

A closed 2 m room, mirror-symmetric about x = 0, lit by a ceiling light.
Its right wall (x = +1) and front wall (z = +1) are wound facing OUT of the
room, so only two-sided shading lights them like their mirror images. Against
the back wall a two-step stair: treads are 4 cm slabs with a 2 cm nosing, and
each riser runs from inside the slab (or floor) below to inside the slab above,
so every corner vertex of a riser is buried in other geometry while the
riser's face is in plain view.
"""
V, F = [], []


def vertex(p):
    V.append(p)
    return len(V)


def quad(a, b, c, d, mat):
    """Two triangles, counter-clockwise a b c d seen from the front."""
    i = [vertex(p) for p in (a, b, c, d)]
    F.append((mat, (i[0], i[1], i[2])))
    F.append((mat, (i[0], i[2], i[3])))


def box(x0, x1, y0, y1, z0, z1, mat):
    """A closed box, faces outward."""
    quad((x0, y1, z1), (x1, y1, z1), (x1, y1, z0), (x0, y1, z0), mat)  # top +y
    quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1), mat)  # bottom -y
    quad((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1), mat)  # front +z
    quad((x1, y0, z0), (x0, y0, z0), (x0, y1, z0), (x1, y1, z0), mat)  # back -z
    quad((x1, y0, z1), (x1, y0, z0), (x1, y1, z0), (x1, y1, z1), mat)  # right +x
    quad((x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0), mat)  # left -x


L, R, B, T, K, N = -1.0, 1.0, 0.0, 2.0, -1.0, 1.0
quad((L, B, N), (R, B, N), (R, B, K), (L, B, K), "floor")      # +y, inward
quad((L, T, K), (R, T, K), (R, T, N), (L, T, N), "ceiling")    # -y, inward
quad((L, B, N), (L, B, K), (L, T, K), (L, T, N), "left")       # +x, inward
quad((R, B, N), (R, B, K), (R, T, K), (R, T, N), "right")      # +x: OUTWARD
quad((L, B, K), (R, B, K), (R, T, K), (L, T, K), "back")       # +z, inward
quad((L, B, N), (R, B, N), (R, T, N), (L, T, N), "front")      # +z: OUTWARD
quad((-0.25, 1.98, -0.25), (0.25, 1.98, -0.25), (0.25, 1.98, 0.25), (-0.25, 1.98, 0.25), "light")  # -y
box(-0.5, 0.5, 0.26, 0.30, -1.0, -0.58, "tread")
box(-0.5, 0.5, 0.56, 0.60, -1.0, -0.78, "tread")
quad((-0.5, -0.01, -0.6), (0.5, -0.01, -0.6), (0.5, 0.28, -0.6), (-0.5, 0.28, -0.6), "riser")  # +z
quad((-0.5, 0.28, -0.8), (0.5, 0.28, -0.8), (0.5, 0.58, -0.8), (-0.5, 0.58, -0.8), "riser")   # +z

albedo = {"floor": 0.7, "ceiling": 0.7, "left": 0.6, "right": 0.6, "back": 0.7, "front": 0.7,
          "light": 0.0, "tread": 0.5, "riser": 0.5}
with open("inverted_room.mtl", "w") as m:
    m.write("# Materials of inverted_room.obj (written by make_inverted_room.py)\n")
    for name, a in albedo.items():
        m.write(f"newmtl {name}\nKd {a} {a} {a}\n" + ("Ke 8 8 8\n" if name == "light" else "") + "\n")
with open("inverted_room.obj", "w") as o:
    o.write("# Written by make_inverted_room.py: a room with outward-wound walls and\n")
    o.write("# stair risers whose corners are buried in the treads.\nmtllib inverted_room.mtl\n")
    for p in V:
        o.write("v %g %g %g\n" % p)
    current = None
    for mat, f in F:
        if mat != current:
            o.write(f"usemtl {mat}\n")
            current = mat
        o.write("f %d %d %d\n" % f)
