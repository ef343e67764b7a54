#!/usr/bin/env python3
"""Kobayashi et al. 2001 benchmark problems 1 and 3 as lpm scenes, and their comparison.

Source: K. Kobayashi, N. Sugimura, Y. Nagaya, "3D radiation transport benchmark problems and results
for simple geometries with void region", Progress in Nuclear Energy 39(2), 119-144 (2001),
doi:10.1016/S0149-1970(01)00007-5 (the OECD/NEA benchmark). One speed, isotropic scattering, cm.

The published problems give one octant with mirror (reflective) planes x = 0, y = 0, z = 0. By
default the generator states the FULL problem: the octant mirrored about the three planes. By the
method of images that is exact: the mirrored problem is symmetric, so no net current crosses the
planes, which is what a mirror imposes; its flux in the octant is the octant problem's. Problem 1
spans [-100, 100]^3, problem 3 [-60, 60] x [-100, 100] x [-60, 60]. With --octant it writes the
octant as published, [0, 100]^3 or [0, 60] x [0, 100] x [0, 60], with reflective faces at x, y,
z = 0 (`[boundary] x = ["reflective", "open"]`, solver.spatial = "constant"): on the CPU backend
an eighth of the voxels, the same answer (exactly where the plan does not nudge directions swept
across a mirror: their slopes times the octant's planes are whole numbers, e.g. k = 5 at 10 or
2 cm voxels); the GPU backend solves it as the full problem it images (its mirrors unfolded).

Regions (octant coordinates, |x|, |y|, |z| of the full domain):
  source: 0-10 in x, y, z; isotropic source S = 1 /cm^3/s; sigma_t = 0.1 /cm
  void:   problem 1: [0, 50]^3 minus the source; problem 3: the dog-leg duct (see VOID_3)
          sigma_t = 1e-4 /cm (density 1e-3 of the medium's 0.1 /cm)
  shield: the rest; sigma_t = 0.1 /cm
  case i: no scattering (albedo 0); case ii: sigma_s = sigma_t / 2 everywhere (albedo 0.5).

Source normalisation: lpm's volumetric source is sigma_a * Le per unit length and steradian, with
Le = e(v) * medium.emission and sigma_a = density * sigma_t * (1 - albedo). An isotropic source of
S particles/cm^3/s emits S / (4 pi) per steradian, so in the source (density 1) the generator sets
e(v) = 1 and emission = S / (4 pi sigma_t (1 - albedo)): 1/(0.4 pi) in case i, 1/(0.2 pi) in case ii.
lpm's fluence is then the benchmark's scalar flux (particles/cm^2/s).

Usage:
  kobayashi.py generate --problem 1 --case i --voxel-size 10 --out DIR [--k 5] [--tolerance 1e-4] [--octant]
      writes DIR/density.raw, DIR/emission.raw, DIR/scene.toml and DIR/detectors.json
  kobayashi.py compare SOLVE_DIR [--scene-dir DIR] [--markdown] [--json FILE]
      reads SOLVE_DIR/fluence.raw and prints lpm against the published values (C/E) per point
      (--json: the same rows as JSON)
Python 3 standard library only.
"""
import argparse
import json
import math
import os
import struct

SIGMA_T = 0.1  # /cm at density 1: source and shield
VOID_DENSITY = 1e-3  # sigma_t 1e-4 /cm in the void
SOURCE = 1.0  # particles /cm^3 /s
ALBEDO = {"i": 0.0, "ii": 0.5}

# Octant extents (cm) and the full mirrored domain's half-widths.
HALF = {1: (100.0, 100.0, 100.0), 3: (60.0, 100.0, 60.0)}

# Problem 3's void: the dog-leg duct, boxes (x0, x1, y0, y1, z0, z1) in octant coordinates.
VOID_3 = [
    (0, 10, 10, 50, 0, 10),
    (0, 30, 50, 60, 0, 10),
    (30, 40, 50, 60, 0, 30),
    (30, 40, 50, 100, 30, 40),
]


def in_box(p, b):
    return b[0] <= p[0] <= b[1] and b[2] <= p[1] <= b[3] and b[4] <= p[2] <= b[5]


def region(problem, p):
    """'source', 'void' or 'shield' at octant point p (a voxel centre: never on a region face)."""
    if max(p) <= 10.0:
        return "source"
    if problem == 1:
        return "void" if max(p) <= 50.0 else "shield"
    return "void" if any(in_box(p, b) for b in VOID_3) else "shield"


# Published fluxes: (label, points, values, relative errors or None). Problem 1 case i and problem
# 3 case i are the analytic ("exact") solutions; case ii the Monte-Carlo (GMVP) values with their
# relative standard deviations. Octant coordinates (cm).
def _line(axis_points, make):
    return [make(a) for a in axis_points]


D = [5 + 10 * i for i in range(10)]
D6 = [5 + 10 * i for i in range(6)]
PUBLISHED = {
    (1, "i"): [
        ("A", _line(D, lambda y: (5, y, 5)), [5.95659E+00, 1.37185E+00, 5.00871E-01, 2.52429E-01, 1.50260E-01,
                                              5.95286E-02, 1.53283E-02, 4.17689E-03, 1.18533E-03, 3.46846E-04], None),
        ("B", _line(D, lambda d: (d, d, d)), [5.95659E+00, 4.70754E-01, 1.69968E-01, 8.68334E-02, 5.25132E-02,
                                              1.33378E-02, 1.45867E-03, 1.75364E-04, 2.24607E-05, 3.01032E-06], None),
        ("C", _line(D, lambda x: (x, 55, 5)), [5.95286E-02, 5.50247E-02, 4.80754E-02, 3.96765E-02, 3.16366E-02,
                                               2.35303E-02, 5.83721E-03, 1.56731E-03, 4.53113E-04, 1.37079E-04], None),
    ],
    (1, "ii"): [
        ("A", _line(D, lambda y: (5, y, 5)),
         [8.29260E+00, 1.87028E+00, 7.13986E-01, 3.84685E-01, 2.53984E-01,
          1.37220E-01, 4.65913E-02, 1.58766E-02, 5.47036E-03, 1.85082E-03],
         [.00021, .00005, .00003, .00004, .00006, .00073, .00117, .00197, .00343, .00619]),
        ("B", _line(D, lambda d: (d, d, d)),
         [8.29260E+00, 6.63233E-01, 2.68828E-01, 1.56683E-01, 1.04405E-01,
          3.02145E-02, 4.06555E-03, 5.86124E-04, 8.66059E-05, 1.12892E-05],
         [.00021, .00004, .00003, .00005, .00011, .00061, .00074, .00116, .00198, .00383]),
        ("C", _line(D, lambda x: (x, 55, 5)),
         [1.37220E-01, 1.27890E-01, 1.13582E-01, 9.59578E-02, 7.82701E-02,
          5.67030E-02, 1.88631E-02, 6.46624E-03, 2.28099E-03, 7.93924E-04],
         [.00073, .00076, .00080, .00088, .00094, .00111, .00189, .00314, .00529, .00890]),
    ],
    (3, "i"): [
        ("A", _line(D, lambda y: (5, y, 5)), [5.95659E+00, 1.37185E+00, 5.00871E-01, 2.52429E-01, 1.50260E-01,
                                              9.91726E-02, 4.22623E-02, 1.14703E-02, 3.24662E-03, 9.48324E-04], None),
        ("B", _line(D6, lambda x: (x, 55, 5)), [9.91726E-02, 2.45041E-02, 4.54477E-03, 1.42960E-03, 2.64846E-04,
                                                9.14210E-05], None),
        ("C", _line(D6, lambda x: (x, 95, 35)), [3.27058E-05, 2.68415E-05, 1.70019E-05, 3.37981E-05, 6.04893E-06,
                                                 3.36460E-06], None),
    ],
    (3, "ii"): [
        ("A", _line(D, lambda y: (5, y, 5)),
         [8.61578E+00, 2.16130E+00, 8.93784E-01, 4.78052E-01, 2.89424E-01,
          1.92698E-01, 1.04982E-01, 3.37544E-02, 1.08158E-02, 3.39632E-03],
         [.00044, .00010, .00008, .00008, .00009, .00010, .00077, .00107, .00163, .00275]),
        ("B", _line(D6, lambda x: (x, 55, 5)),
         [1.92698E-01, 6.72147E-02, 2.21799E-02, 9.90646E-03, 3.39066E-03, 1.05629E-03],
         [.00010, .00019, .00028, .00033, .00195, .00327]),
        ("C", _line(D6, lambda x: (x, 95, 35)),
         [3.44804E-04, 2.91825E-04, 2.05793E-04, 2.62086E-04, 1.05367E-04, 4.44962E-05],
         [.00793, .00659, .00529, .00075, .00402, .00440]),
    ],
}


def grid(problem, h, octant=False):
    """Dims of the full mirrored domain (or the octant) at voxel size h; an error unless the detectors
    are voxel centres."""
    dims = []
    for half in HALF[problem]:
        n = (1 if octant else 2) * half / h
        # Detector coordinate 5 must be a voxel centre: (5 + half) / h - 0.5 an integer.
        c = (5.0 + half) / h - 0.5
        if abs(n - round(n)) > 1e-9 or abs(c - round(c)) > 1e-9:
            raise SystemExit(
                f"--voxel-size {h}: the detectors (5, 15, ... cm) must be voxel centres and the domain "
                f"a whole number of voxels; use 10, 10/3 (3.3333333333333335), 2 or 10/7, ..."
            )
        dims.append(int(round(n)))
    return dims


def low_corner(problem, octant):
    """The domain's low corner (cm): the origin for the octant, minus the half-widths for the full domain."""
    return [0.0 if octant else -HALF[problem][a] for a in range(3)]


def centre(problem, h, axis, i, octant=False):
    return low_corner(problem, octant)[axis] + (i + 0.5) * h


def voxel_of(problem, h, p, octant=False):
    """Index of the voxel whose centre is octant point p (in the +x, +y, +z octant of the full domain)."""
    return [int(round((p[a] - low_corner(problem, octant)[a]) / h - 0.5)) for a in range(3)]


def generate(args):
    problem, case, h = args.problem, args.case, args.voxel_size
    octant = args.octant
    dims = grid(problem, h, octant)
    os.makedirs(args.out, exist_ok=True)
    nx, ny, nz = dims
    dens = bytearray()
    emis = bytearray()
    counts = {"source": 0, "void": 0, "shield": 0}
    pack = struct.Struct("<f")
    one, void, zero = pack.pack(1.0), pack.pack(VOID_DENSITY), pack.pack(0.0)
    for k in range(nz):
        z = abs(centre(problem, h, 2, k, octant))
        for j in range(ny):
            y = abs(centre(problem, h, 1, j, octant))
            for i in range(nx):
                x = abs(centre(problem, h, 0, i, octant))
                r = region(problem, (x, y, z))
                counts[r] += 1
                dens += void if r == "void" else one
                emis += one if r == "source" else zero
    for name, data in (("density.raw", dens), ("emission.raw", emis)):
        tmp = os.path.join(args.out, name + ".tmp")
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, os.path.join(args.out, name))
    albedo = ALBEDO[case]
    le = SOURCE / (4.0 * math.pi * SIGMA_T * (1.0 - albedo))
    lo = low_corner(problem, octant)
    stated = ("the octant as published, with mirrors at x = 0, y = 0, z = 0" if octant else
              "the octant problem mirrored about x = 0, y = 0, z = 0 (exact by the method of\n# images)")
    scene = f"""# Kobayashi et al. 2001, problem {problem} case {case} (generated by tools/benchmarks/kobayashi.py;
# see its docstring): {stated}, voxel size {h} cm. Fluence = the benchmark's scalar flux (particles/cm^2/s).
[volume]
raw = "density.raw"            # 1 in source and shield, {VOID_DENSITY} in the void
emission_raw = "emission.raw"  # 1 in the source cube, 0 elsewhere
dims = [{nx}, {ny}, {nz}]
voxel_size = {h!r}
origin = [{lo[0]!r}, {lo[1]!r}, {lo[2]!r}]

[medium]
sigma_t = {SIGMA_T}              # /cm at density 1
albedo = {albedo}
g = 0.0
emission = {le!r}  # S / (4 pi sigma_a): the source sigma_a Le is S/(4 pi) per sr and cm^3

[solver]
directions_per_face = {args.k}
tolerance = {args.tolerance}
max_orders = {args.max_orders}
"""
    if args.spatial:
        scene += f'spatial = "{args.spatial}"\n'
    if octant:
        scene += """
[boundary]                     # the published reflective planes; the far faces are vacuum
x = ["reflective", "open"]
y = ["reflective", "open"]
z = ["reflective", "open"]
"""
    with open(os.path.join(args.out, "scene.toml"), "w") as f:
        f.write(scene)
    detectors = []
    for label, points, values, errors in PUBLISHED[(problem, case)]:
        for n, (p, v) in enumerate(zip(points, values)):
            detectors.append({
                "set": label, "point": list(p), "voxel": voxel_of(problem, h, p, octant), "published": v,
                "published_rel_err": None if errors is None else errors[n],
            })
    meta = {
        "problem": problem, "case": case, "voxel_size": h, "octant": octant, "dims": dims, "regions": counts,
        "source_power": SOURCE * counts["source"] * h ** 3, "detectors": detectors,
    }
    with open(os.path.join(args.out, "detectors.json"), "w") as f:
        json.dump(meta, f, indent=1)
    print(f"problem {problem} case {case}: {nx}x{ny}x{nz} voxels of {h} cm, {counts} -> {args.out}")


def compare(args):
    scene_dir = args.scene_dir or args.solve_dir
    with open(os.path.join(scene_dir, "detectors.json")) as f:
        meta = json.load(f)
    nx, ny, nz = meta["dims"]
    with open(os.path.join(args.solve_dir, "fluence.json")) as f:
        desc = json.load(f)
    channels = desc.get("channels", 1)
    with open(os.path.join(args.solve_dir, "fluence.raw"), "rb") as f:
        raw = f.read()
    if len(raw) != 4 * channels * nx * ny * nz:
        raise SystemExit(f"{args.solve_dir}/fluence.raw: {len(raw)} bytes, expected {4 * channels * nx * ny * nz}")

    def phi(v):
        i = ((v[2] * ny + v[1]) * nx + v[0]) * channels
        return struct.unpack_from("<f", raw, 4 * i)[0]

    rows = []
    for d in meta["detectors"]:
        c = phi(d["voxel"])
        rows.append((d["set"], d["point"], c, d["published"], c / d["published"], d["published_rel_err"]))
    if args.markdown:
        print("| set | point (cm) | lpm | published | C/E |")
        print("|---|---|---|---|---|")
        for s, p, c, e, ce, err in rows:
            pe = f"{e:.5e}" + ("" if err is None else f" ({err:.5f})")
            print(f"| {s} | ({p[0]}, {p[1]}, {p[2]}) | {c:.5e} | {pe} | {ce:.3f} |")
    else:
        for s, p, c, e, ce, err in rows:
            print(f"{s} {tuple(p)!s:16} lpm {c:.5e} published {e:.5e} C/E {ce:.3f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump([{"set": s, "point": p, "lpm": c, "published": e, "c_over_e": ce}
                       for s, p, c, e, ce, _ in rows], f, indent=1)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate")
    g.add_argument("--problem", type=int, choices=[1, 3], required=True)
    g.add_argument("--case", choices=["i", "ii"], required=True)
    g.add_argument("--voxel-size", type=float, default=10.0)
    g.add_argument("--out", required=True)
    g.add_argument("--k", type=int, default=5)
    g.add_argument("--tolerance", type=float, default=1e-4)
    g.add_argument("--max-orders", type=int, default=200)
    g.add_argument("--spatial", choices=["constant", "linear"])
    g.add_argument("--octant", action="store_true",
                   help="the published octant with reflective faces at x, y, z = 0 (else the mirrored full domain)")
    c = sub.add_parser("compare")
    c.add_argument("solve_dir")
    c.add_argument("--scene-dir")
    c.add_argument("--markdown", action="store_true")
    c.add_argument("--json")
    args = ap.parse_args()
    generate(args) if args.cmd == "generate" else compare(args)


if __name__ == "__main__":
    main()
