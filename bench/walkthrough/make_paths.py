#!/usr/bin/env python3
"""Writes the walkthrough's camera paths (walk-a..d.json) for scenes/bathroom.json.

Each path: stand 4 s, walk 6 s, stand 4 s, turn 90 degrees in 2 s, stand 4 s,
turn back in 2 s (a pose seen before), stand 4 s, walk back in 6 s to the
start's pose, stand 6 s: 38 s. The four walk different parts of the room.
"""
import json
import os

WIDTH, HEIGHT, FOV = 240, 135, 60
EAST, NORTH, WEST, SOUTH = (3.8, -0.45, -0.3), (0.0, -0.3, -3.0), (-3.8, -0.45, 0.3), (0.0, -0.3, 3.0)


def keyframe(t, eye, direction):
    return {"t": t, "eye": list(eye), "target": [round(e + d, 4) for e, d in zip(eye, direction)], "up": [0, 1, 0]}


def shape(start, stop, look, turn):
    keys = [(0, start, look), (4, start, look), (10, stop, look), (14, stop, look), (16, stop, turn),
            (20, stop, turn), (22, stop, look), (26, stop, look), (32, start, look), (38, start, look)]
    return [keyframe(*k) for k in keys]


PATHS = {
    "walk-a": shape((-2.2, 1.45, -1.3), (-0.9, 1.45, -1.3), EAST, NORTH),
    "walk-b": shape((0.0, 1.45, -1.3), (-1.4, 1.45, -1.3), WEST, SOUTH),
    "walk-c": shape((-1.6, 1.5, -0.6), (-0.4, 1.5, -0.6), NORTH, WEST),
    "walk-d": shape((-1.8, 1.4, -2.0), (-0.6, 1.4, -2.0), EAST, SOUTH),
}

if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    for name, keys in PATHS.items():
        with open(os.path.join(here, name + ".json"), "w") as f:
            json.dump({"name": name, "fov_y_deg": FOV, "width": WIDTH, "height": HEIGHT, "keyframes": keys}, f, indent=1)
            f.write("\n")
