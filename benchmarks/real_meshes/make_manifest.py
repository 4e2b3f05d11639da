"""How ``manifest.json`` was made: rules that PROPOSE each shape's part map and rotation, then the hand
corrections (``OVERRIDES``) made after looking at every shape's picture (``load.py --png``).

Run again only to regenerate the manifest from the same sources (the roots as in ``README.md``)::

    python benchmarks/real_meshes/make_manifest.py --root diegogb=/work/realsrc/diegogb \\
        --root flightairmap=/work/realsrc/flightairmap --root quaternius=/work/realsrc/quaternius

The rules are a starting point, not the labels: the committed manifest (every name and colour listed with its
part) is what the loader uses, and what a reviewer checks.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import load  # noqa: E402

DIEGOGB = {"repo": "diegogb/3D_Synthesis_based_on_Fine-grained_Parts",
           "commit": "75ad67b3382ceac9383a3e14b0cdcac9aa59fb3c"}
FLIGHTAIRMAP = {"repo": "Ysurac/FlightAirMap-3dmodels", "commit": "0906d9ba1bdd906ce45807e45ed706c09912db19"}
QUATERNIUS = {"repo": "trebeljahr/quaternius-showcase", "commit": "eab2e43a7e688dad1cc6be764c1c4ba593e1961c"}
PYVISTA = {"package": "pyvista", "version": "0.49.2"}

# Table meshes and the segmentation file that matches each (checked by the two-sided distance between the
# segment points and points sampled on the mesh: 0.04-0.07 for these pairs, 0.17 or more for every other
# pair). Table4's segments are in seg-Table3.ply; seg-Table6 and seg-Table12, seg-Table7 and seg-Table13 are
# identical files. Table3, 11, 12 and 13 match no segmentation file; Table2, 5 and 14 have no mesh in the
# repository (too large for the snapshot): all seven are left out.
TABLE_SEGMENTS = {"Table1": "seg-Table1", "Table4": "seg-Table3", "Table6": "seg-Table6", "Table7": "seg-Table7",
                  "Table8": "seg-Table8", "Table9": "seg-Table9", "Table10": "seg-Table10",
                  "Table15": "seg-Table15"}

# FlightAirMap models kept: the airplanes whose glTF 2 file keeps the FlightGear object names. Left out:
# helicopters (B407, EC35), the paraglider, and files whose objects were merged into one or a few unnamed
# meshes (707, BCS3, C421, DHC4, E145, E75L, MD11, P40, PA22, PC21, T134), and 757.glb (the same as B752.glb).
AIRPLANES = ["a320/glTF2/A319.glb", "a320/glTF2/A320.glb", "a320/glTF2/A321.glb", "a332/glTF2/A332.glb",
             "a333/glTF2/A333.glb", "a350/glTF2/A350.glb", "ask21/glTF2/AS21.glb", "atr42/glTF2/AT45.glb",
             "atr72/glTF2/AT75.glb", "b744/glTF2/B747.glb", "b748/glTF2/B748.glb", "b752/glTF2/B752.glb",
             "b788/glTF2/B788.glb", "bcs1/glTF2/BCS1.glb", "c208/glTF2/C208.glb", "c550/glTF2/C550.glb",
             "crj2/glTF2/CRJ2.glb", "crj9/glTF2/CRJ7.glb", "crj9/glTF2/CRJ9.glb", "dr40/glTF2/DR40.glb",
             "e190/glTF2/E170.glb", "e190/glTF2/E190.glb", "pa18/glTF2/PA18.glb", "pa28/glTF2/PA28.glb",
             "pa32/glTF2/PA32.glb", "pc12/glTF2/PC12.glb", "sr22/glTF2/SR22.glb"]

# Licence per FlightAirMap folder: its own licence file where it has one (atr72: GPL-3.0; atr42, b748, b752,
# crj9, e190: GPL-2 or later), else the FlightGear aircraft's GPL-2.0-or-later (the repository README names
# FlightGear / FGMEMBERS as the source and has no licence file of its own).
AIRPLANE_LICENCE = {"atr72": "GPL-3.0-or-later"}

ANIMALS = ["Alpaca", "Bull", "Cow", "Deer", "Donkey", "Fox", "Horse", "Husky", "ShibaInu", "Stag", "Wolf"]

# Hand corrections after looking at the pictures: {shape id: {name: part}}.
OVERRIDES: dict[str, dict[str, str]] = {
    # flap-track fairings under the wings
    **{f"airplane_{a}": {"FairingL1": "wing", "FairingL2": "wing", "FairingR1": "wing", "FairingR2": "wing"}
       for a in ("A319", "A320", "A321")},
    "airplane_B788": {"no1engl": "engine", "no2engl": "engine"},
    "airplane_CRJ2": {"no1engchrome": "engine", "no2engchrome": "engine"},
    "airplane_C208": {"bulbe": "wing", "barres": "wing"},  # a pod under the left wing; the wing struts
    "airplane_PC12": {"ajout": "tail", "bosse": "wing"},  # the T-tail's top fairing; a wing-tip fairing
}
# Hand-set rotations (rows), where the rule's guess was wrong.
ROTATIONS: dict[str, list[list[float]]] = {
    # pyvista's airplane: the fuselage along y with the nose at -y, the fin toward +z
    "airplane_pyvista": [[1, 0, 0], [0, 0, 1], [0, -1, 0]],
}


def rotation(up: np.ndarray, front: np.ndarray) -> np.ndarray:
    """Rows: the file directions that become the networks' x, y (up) and z (front)."""
    up, front = np.asarray(up, float), np.asarray(front, float)
    return np.stack([np.cross(up, front), up, front])


def _axis(v: np.ndarray) -> np.ndarray:
    """The signed coordinate axis nearest a direction."""
    a = np.zeros(3)
    i = int(np.argmax(np.abs(v)))
    a[i] = np.sign(v[i]) or 1.0
    return a


def _hex(c) -> str:
    return "#%02x%02x%02x" % tuple(int(x) for x in c)


def _segments(path: Path):
    """Points, colours and normals of a segmentation PLY (ASCII: x y z red green blue nx ny nz)."""
    lines = path.read_text().splitlines()
    start = lines.index("end_header") + 1
    table = np.array([row.split() for row in lines[start:] if row.strip()], float)
    return table[:, :3], np.array([_hex(c) for c in table[:, 3:6]]), table[:, 6:9]


def _chair(root: Path, name: str):
    pts, hexes, nrm = _segments(root / f"data/input/Chairs/seg-{name}.ply")
    up = np.array([0.0, 1.0, 0.0])
    flat = (nrm[:, 1] > 0.9) & (pts[:, 1] > -0.7) & (pts[:, 1] < 0.5)
    hist, edges = np.histogram(pts[flat, 1], bins=np.arange(-0.7, 0.52, 0.02))
    h = edges[np.argmax(hist)] + 0.02
    above = pts[:, 1] > h + 0.25
    level = np.abs(pts[:, 1] - h) < 0.1
    d = pts[above].mean(0) - pts[level].mean(0)
    d[1] = 0
    rot = rotation(up, -_axis(d))
    q = pts @ rot.T
    half_x, zmin, depth, width = np.abs(q[:, 0]).max(), q[:, 2].min(), np.ptp(q[:, 2]), np.ptp(q[:, 0])
    arms = name.startswith("ChairArms")
    stats = {c: q[hexes == c] for c in np.unique(hexes)}
    # the seat: segments wide in x and z, not tall, between the floor region and the top of the back
    seat = [c for c, s in stats.items() if np.ptp(s[:, 0]) > 0.3 * width and np.ptp(s[:, 2]) > 0.3 * depth
            and np.ptp(s[:, 1]) < 0.4 and -0.7 < s[:, 1].mean() < 0.35]
    if seat:
        ys = np.concatenate([stats[c][:, 1] for c in seat])
        top, mid = np.percentile(ys, 98), (np.percentile(ys, 98) + np.percentile(ys, 2)) / 2
    else:
        top, mid = h, h - 0.05
    parts = {}
    for c, s in stats.items():
        cy, cx, cz = s[:, 1].mean(), np.abs(s[:, 0]).mean(), s[:, 2].mean()
        if c in seat:
            parts[c] = "seat"
        elif cy < mid:
            parts[c] = "leg"
        elif cy <= top + 0.02:
            parts[c] = "seat" if cz > zmin + 0.15 * depth else "back"
        elif arms and cx > 0.6 * half_x and cz > zmin + 0.3 * depth:
            parts[c] = "arm"
        else:
            parts[c] = "back"
    return rot, parts


def _table(root: Path, mesh: str, seg: str):
    pts, hexes, nrm = _segments(root / f"data/input/Tables/{seg}.ply")
    best = None
    for i in range(3):
        for sign in (1, -1):
            ext = pts[:, i].max() if sign > 0 else pts[:, i].min()
            n = ((sign * nrm[:, i] > 0.95) & (np.abs(pts[:, i] - ext) < 0.03)).sum()
            if best is None or n > best[0]:
                best = (n, i, sign)
    up = np.zeros(3)
    up[best[1]] = best[2]
    horiz = [i for i in range(3) if i != best[1]]
    long_axis = horiz[int(np.argmax([np.ptp(pts[:, i]) for i in horiz]))]
    front = np.zeros(3)
    front[[i for i in horiz if i != long_axis][0]] = 1.0
    rot = rotation(up, front)
    if np.linalg.det(rot) < 0:
        rot = rotation(up, -front)
    q = pts @ rot.T
    top, height, width, depth = q[:, 1].max(), np.ptp(q[:, 1]), np.ptp(q[:, 0]), np.ptp(q[:, 2])
    # the top: segments reaching the top surface and wide in both horizontal directions (the tops are split
    # into quarters), or lying wholly within the highest tenth of the height
    parts = {}
    for c in np.unique(hexes):
        s = q[hexes == c]
        wide = np.ptp(s[:, 0]) > 0.3 * width and np.ptp(s[:, 2]) > 0.3 * depth
        high = s[:, 1].max() > top - 0.03 * height
        parts[c] = "top" if (wide and high) or s[:, 1].min() > top - 0.1 * height else "leg"
    return rot, parts


_AIR_RULES = [
    ("ignore", r"propdisc|propblur|blur|rotor_disc|shadow"),
    ("engine", r"engine|eng[._]?\d|enge|engcore|engnose|engfan|nacelle|revers|fan|intake|exhaust|nozzle|spinner|"
               r"^cone|helice|blade|pylon|turbofan|^bol$|prop|nosecone|corpo_front"),
    ("tail", r"stab|elevator|rudder|^fin|tail|profondeur|direction|empennage|lightedfin"),
    ("wing", r"wing|aileron|flap|slat|spoiler|ailes|volet|winglet|speedbrake"),
]


def _air_part(name: str) -> str:
    low = name.lower()
    for part, pattern in _AIR_RULES:
        if re.search(pattern, low):
            return part
    return "body"


def _airplane(root: Path, path: str):
    pieces = load.read_pieces(root / path)
    parts = {p.name: _air_part(p.name) for p in pieces}
    return pieces, parts


def _airplane_rotation(pieces, parts) -> np.ndarray:
    def centroid(part):
        v = [p.vertices[p.faces].mean(1) for p in pieces if parts[p.name] == part]
        return np.concatenate(v).mean(0) if v else None
    up = np.array([0.0, 1.0, 0.0])
    d = centroid("tail") - centroid("wing")
    d[1] = 0
    return rotation(up, -_axis(d))


_GENERIC = r"^(cube|cylinder|circle|plane|misc|w\d+|untitled|mesh|group|color|box|sphere|fuselage\.\d|core|casing)"


def _outboard_generic_nodes(pieces, parts, rot) -> None:
    """A node with a generic name ('Cube.004', 'cylinder.006', 'W05.206', ...) labelled body by the name rules
    but lying outboard of the fuselage takes the part of the nearest named wing, tail or engine node."""
    def area(p):
        t = p.vertices[p.faces]
        return np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
    fus = max((p for p in pieces if re.search("fuselage|body", p.name.lower())), key=area)
    fv = fus.vertices @ rot.T
    centre, half = np.median(fv[:, 0]), np.percentile(np.abs(fv[:, 0] - np.median(fv[:, 0])), 99)
    named = [(p, parts[p.name]) for p in pieces
             if parts[p.name] in ("wing", "tail", "engine") and not re.search(_GENERIC, p.name.lower())]
    if not named:
        return
    ref = np.concatenate([p.vertices[::max(1, len(p.vertices) // 400)] @ rot.T for p, _ in named])
    ref_part = np.concatenate([[part] * len(p.vertices[::max(1, len(p.vertices) // 400)]) for p, part in named])
    for p in pieces:
        if parts[p.name] != "body" or not re.search(_GENERIC, p.name.lower()):
            continue
        c = (p.vertices @ rot.T).mean(0)
        if abs(c[0] - centre) > 1.3 * half:
            parts[p.name] = str(ref_part[np.argmin(((ref - c) ** 2).sum(1))])


def _rear_wings_are_tail(pieces, parts, rot) -> None:
    """A 'wing' node whose centre lies in the rearmost fifth of the aircraft is a horizontal tail surface."""
    allv = np.concatenate([p.vertices for p in pieces]) @ rot.T
    zmin, length = allv[:, 2].min(), np.ptp(allv[:, 2])
    for p in pieces:
        if parts[p.name] == "wing":
            c = (p.vertices @ rot.T)[:, 2].mean()
            if c < zmin + 0.2 * length:
                parts[p.name] = "tail"


_ANIMAL_RULES = [
    ("tail", r"^tail"),
    ("head", r"neck|head|ear|jaw|horn|antler|eye|mouth|tongue|nose"),
    ("leg", r"upperleg|lowerleg|backleg|frontleg|^ffb?\.|^ik|foot|hoof|toe|poletarget"),
    ("body", r"body|back|torso|hip|spine|chest|shoulder|root|pelvis"),
]


def _animal_part(name: str) -> str:
    low = name.lower()
    for part, pattern in _ANIMAL_RULES:
        if re.search(pattern, low):
            return part
    raise ValueError(f"no rule for joint {name}")


def _animal(root: Path, name: str):
    pieces = load.read_pieces(root / f"public/glb/animals_pack/{name}.glb")
    names = {j for p in pieces for j in (p.joints or [])} | {p.name for p in pieces if p.weights is None}
    return {n: _animal_part(n) for n in sorted(names)}


def _entry(sid, category, root, source, path, licence, attribution, rot, labels):
    return {"id": sid, "category": category, "root": root, "source": dict(source, path=path), "licence": licence,
            "attribution": attribution, "to_network": np.round(rot, 6).tolist(), "labels": labels}


def build(roots: dict[str, Path]) -> list[dict]:
    shapes = []
    gonzalez = ("Diego Gonzalez and Oliver van Kaick, '3D synthesis of man-made objects based on fine-grained "
                "parts', Computers & Graphics 74 (2018); input meshes and fine-grained segmentations from their "
                "repository (the meshes themselves from the collections the paper cites)")
    chairs = sorted(p.stem for p in (roots["diegogb"] / "data/input/Chairs").glob("Chair*.obj"))
    for name in chairs:
        rot, parts = _chair(roots["diegogb"], name)
        sid = f"chair_{name}"
        parts.update(OVERRIDES.get(sid, {}))
        shapes.append(_entry(sid, "chair", "diegogb", DIEGOGB, f"data/input/Chairs/{name}.obj", "GPL-3.0-only",
                             gonzalez, np.array(ROTATIONS.get(sid, rot)),
                             {"by": "segment_colour", "segments": f"data/input/Chairs/seg-{name}.ply",
                              "map": dict(sorted(parts.items()))}))
    for name, seg in TABLE_SEGMENTS.items():
        rot, parts = _table(roots["diegogb"], name, seg)
        sid = f"table_{name}"
        parts.update(OVERRIDES.get(sid, {}))
        shapes.append(_entry(sid, "table", "diegogb", DIEGOGB, f"data/input/Tables/{name}.obj", "GPL-3.0-only",
                             gonzalez, np.array(ROTATIONS.get(sid, rot)),
                             {"by": "segment_colour", "segments": f"data/input/Tables/{seg}.ply",
                              "map": dict(sorted(parts.items()))}))
    for path in AIRPLANES:
        pieces, parts = _airplane(roots["flightairmap"], path)
        sid = f"airplane_{Path(path).stem}"
        parts.update(OVERRIDES.get(sid, {}))
        rot = ROTATIONS.get(sid, _airplane_rotation(pieces, parts))
        _rear_wings_are_tail(pieces, parts, np.asarray(rot))
        _outboard_generic_nodes(pieces, parts, np.asarray(rot))
        parts.update(OVERRIDES.get(sid, {}))
        folder = path.split("/")[0]
        shapes.append(_entry(sid, "airplane", "flightairmap", FLIGHTAIRMAP, path,
                             AIRPLANE_LICENCE.get(folder, "GPL-2.0-or-later"),
                             "FlightGear aircraft model (FGMEMBERS / FlightGear contributors), converted to glTF 2 "
                             "by Ysurac for FlightAirMap", np.array(rot),
                             {"by": "node", "map": dict(sorted(parts.items()))}))
    for name in ANIMALS:
        parts = _animal(roots["quaternius"], name)
        sid = f"animal_{name}"
        parts.update(OVERRIDES.get(sid, {}))
        shapes.append(_entry(sid, "animal", "quaternius", QUATERNIUS, f"public/glb/animals_pack/{name}.glb",
                             "CC0-1.0", "Quaternius, Ultimate Animated Animal Pack (CC0); glb files as collected "
                             "in trebeljahr/quaternius-showcase", np.array(ROTATIONS.get(sid, np.eye(3))),
                             {"by": "skin_joint", "map": parts}))
    pv = "The PyVista Developers, pyvista example mesh (MIT); data_samples/real/pyvista/LICENSE"
    shapes.append(_entry("airplane_pyvista", "airplane", "pyvista", PYVISTA, "airplane.ply", "MIT", pv,
                         np.array(ROTATIONS.get("airplane_pyvista", np.eye(3))), None))
    shapes.append(_entry("animal_pyvista_ant", "animal", "pyvista", PYVISTA, "ant.ply", "MIT", pv,
                         np.array(ROTATIONS.get("animal_pyvista_ant", np.eye(3))), None))
    for s in shapes:
        if s["labels"] is None:
            del s["labels"]
    return shapes


def write(shapes: list[dict], path: Path) -> None:
    """One shape per block, each label map one entry a line, so that a diff shows one changed part a line."""
    roots = {
        "diegogb": dict(DIEGOGB, licence="GPL-3.0-only", files="data/input/Chairs, data/input/Tables"),
        "flightairmap": dict(FLIGHTAIRMAP, licence="GPL-2.0-or-later (FlightGear models; atr72 GPL-3.0)",
                             files="*/glTF2/*.glb"),
        "quaternius": dict(QUATERNIUS, licence="CC0-1.0 (Quaternius)", files="public/glb/animals_pack/*.glb"),
        "pyvista": dict(PYVISTA, licence="MIT", files="data_samples/real/pyvista/ in this repository"),
    }
    text = json.dumps({"version": 1, "frame": "networks: +y up, facing +z; to_network @ p_file = p_network",
                       "roots": roots, "shapes": shapes}, indent=1)
    path.write_text(text + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--root", action="append", default=[], metavar="NAME=PATH")
    parser.add_argument("--out", type=Path, default=HERE / "manifest.json")
    args = parser.parse_args()
    roots = load._parse_roots(args.root)
    write(build(roots), args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
