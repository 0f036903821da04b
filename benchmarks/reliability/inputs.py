"""The probe's hostile inputs, generated into a folder with fixed seeds: broken and lying mesh files, fine meshes,
STEP files, huge and crafted images and arrays, calibration data files.

:func:`make` builds one input by its file name (``make(folder, "garbage.stl")``) and returns its path; an input is
built once per folder. :data:`GENERATORS` lists the names.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

__all__ = ["GENERATORS", "make", "step_boxes"]

SEED = 39


def _rng(name: str) -> np.random.Generator:
    return np.random.default_rng([SEED, *name.encode()])


def _cube() -> trimesh.Trimesh:
    """The probe's cube: 100 mm, standing on z = 0 (the geometry of parts/objectA_wuerfel.stl)."""
    cube = trimesh.creation.box((100.0, 100.0, 100.0))
    cube.apply_translation((0.0, 0.0, 50.0))
    return cube


def _stl_bytes(mesh: trimesh.Trimesh) -> bytes:
    return mesh.export(file_type="stl")


# ------------------------------------------------------------------------------------------------------- meshes
def _garbage(path: Path) -> None:
    path.write_bytes(_rng(path.name).bytes(4096))


def _garbage_ply(path: Path) -> None:
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\n"
    header += b"property float z\nend_header\n"
    path.write_bytes(header + _rng(path.name).bytes(4096))


def _truncated_stl(path: Path) -> None:
    data = _stl_bytes(trimesh.creation.icosphere(subdivisions=2, radius=50.0))
    path.write_bytes(data[: len(data) // 2])


def _count_lie_stl(path: Path) -> None:
    path.write_bytes(b"\0" * 80 + struct.pack("<I", 2**32 - 1) + b"\0" * 50)


def _nan_stl(path: Path) -> None:
    data = bytearray(_stl_bytes(_cube()))
    data[84 + 12 : 84 + 16] = struct.pack("<f", float("nan"))  # the first vertex's x
    path.write_bytes(bytes(data))


def _huge_stl(path: Path) -> None:
    cube = _cube()
    cube.apply_scale(1e7)  # 1e9 mm
    path.write_bytes(_stl_bytes(cube))


def _huge_obj(path: Path) -> None:
    cube = _cube()
    lines = [f"v {x * 5e297:.6e} {y * 5e297:.6e} {z * 5e297:.6e}" for x, y, z in cube.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in cube.faces]
    path.write_text("\n".join(lines) + "\n")


def _sphere(subdivisions: int) -> Callable[[Path], None]:
    def build(path: Path) -> None:
        sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=50.0)
        sphere.apply_translation((0.0, 0.0, 50.0))
        path.write_bytes(_stl_bytes(sphere))

    return build


def _absent(path: Path) -> None:
    """A name that stays missing."""


def _directory(path: Path) -> None:
    path.mkdir()


def _devzero(path: Path) -> None:
    path.symlink_to("/dev/zero")


def _fifo(path: Path) -> None:
    os.mkfifo(path)


# --------------------------------------------------------------------------------------------------------- STEP
def step_boxes(count: int, size_mm: float = 10.0, pitch_mm: float = 15.0) -> str:
    """An AP214 file of ``count`` boxes (six planar ``ADVANCED_FACE``s each) on a grid, in millimetres."""
    lines: list[str] = []

    def add(text: str) -> int:
        lines.append(text)
        return len(lines)

    def point(p) -> int:
        return add(f"CARTESIAN_POINT('',({p[0]:.4f},{p[1]:.4f},{p[2]:.4f}))")

    def direction(d) -> int:
        return add(f"DIRECTION('',({d[0]:.1f},{d[1]:.1f},{d[2]:.1f}))")

    side = max(1, round(count ** (1 / 3) + 0.5))
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float) * size_mm
    # faces as corner indices, counter-clockwise seen from outside, with their outward normals
    quads = [
        ((0, 2, 3, 1), (0, 0, -1)),
        ((4, 5, 7, 6), (0, 0, 1)),
        ((0, 1, 5, 4), (0, -1, 0)),
        ((2, 6, 7, 3), (0, 1, 0)),
        ((0, 4, 6, 2), (-1, 0, 0)),
        ((1, 3, 7, 5), (1, 0, 0)),
    ]
    solids = []
    for k in range(count):
        offset = np.array([k % side, (k // side) % side, k // (side * side)], float) * pitch_mm
        vertices = [add(f"VERTEX_POINT('',#{point(c + offset)})") for c in corners]
        edges: dict[tuple[int, int], int] = {}

        def edge(a: int, b: int, edges=edges, offset=offset, vertices=vertices) -> str:
            key = (min(a, b), max(a, b))
            if key not in edges:
                pa, pb = corners[key[0]] + offset, corners[key[1]] + offset
                vector = add(f"VECTOR('',#{direction((pb - pa) / np.linalg.norm(pb - pa))},1.0)")
                line = add(f"LINE('',#{point(pa)},#{vector})")
                edges[key] = add(f"EDGE_CURVE('',#{vertices[key[0]]},#{vertices[key[1]]},#{line},.T.)")
            return f"ORIENTED_EDGE('',*,*,#{edges[key]},{'.T.' if a == key[0] else '.F.'})"

        faces = []
        for quad, normal in quads:
            oriented = [add(edge(quad[i], quad[(i + 1) % 4])) for i in range(4)]
            loop = add(f"EDGE_LOOP('',({','.join(f'#{o}' for o in oriented)}))")
            bound = add(f"FACE_OUTER_BOUND('',#{loop},.T.)")
            ref = (1, 0, 0) if abs(normal[0]) < 0.5 else (0, 1, 0)
            axis = add(
                f"AXIS2_PLACEMENT_3D('',#{point(corners[quad[0]] + offset)},#{direction(normal)},#{direction(ref)})"
            )
            plane = add(f"PLANE('',#{axis})")
            faces.append(add(f"ADVANCED_FACE('',(#{bound}),#{plane},.T.)"))
        shell = add(f"CLOSED_SHELL('',({','.join(f'#{f}' for f in faces)}))")
        solids.append(add(f"MANIFOLD_SOLID_BREP('box{k}',#{shell})"))
    origin = add(f"AXIS2_PLACEMENT_3D('',#{point((0, 0, 0))},#{direction((0, 0, 1))},#{direction((1, 0, 0))})")
    length = add("( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) )")
    angle = add("( NAMED_UNIT(*) PLANE_ANGLE_UNIT() SI_UNIT($,.RADIAN.) )")
    solid_angle = add("( NAMED_UNIT(*) SI_UNIT($,.STERADIAN.) SOLID_ANGLE_UNIT() )")
    uncertainty = add(f"UNCERTAINTY_MEASURE_WITH_UNIT(LENGTH_MEASURE(1.E-05),#{length},'distance_accuracy_value','')")
    context = add(
        "( GEOMETRIC_REPRESENTATION_CONTEXT(3) GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT((#"
        f"{uncertainty})) GLOBAL_UNIT_ASSIGNED_CONTEXT((#{length},#{angle},#{solid_angle})) "
        "REPRESENTATION_CONTEXT('Context #1','3D Context with UNIT and UNCERTAINTY') )"
    )
    shape = add(f"ADVANCED_BREP_SHAPE_REPRESENTATION('',({','.join(f'#{s}' for s in solids)},#{origin}),#{context})")
    app = add("APPLICATION_CONTEXT('automotive_design')")
    add(f"APPLICATION_PROTOCOL_DEFINITION('draft international standard','automotive_design',1998,#{app})")
    mech = add(f"MECHANICAL_CONTEXT('',#{app},'mechanical')")
    product = add(f"PRODUCT('boxes','boxes','',(#{mech}))")
    formation = add(f"PRODUCT_DEFINITION_FORMATION('','',#{product})")
    design = add(f"PRODUCT_DEFINITION_CONTEXT('part definition',#{app},'design')")
    definition = add(f"PRODUCT_DEFINITION('design','',#{formation},#{design})")
    shape_def = add(f"PRODUCT_DEFINITION_SHAPE('','',#{definition})")
    add(f"SHAPE_DEFINITION_REPRESENTATION(#{shape_def},#{shape})")
    body = "\n".join(f"#{i}={text};" for i, text in enumerate(lines, start=1))
    return (
        "ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('boxes'),'2;1');\nFILE_NAME('boxes.step','2026-01-01T00:00:00',"
        "(''),(''),'','','');\nFILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));\nENDSEC;\nDATA;\n"
        f"{body}\nENDSEC;\nEND-ISO-10303-21;\n"
    )


def _step(count: int, size_mm: float = 10.0) -> Callable[[Path], None]:
    def build(path: Path) -> None:
        path.write_text(step_boxes(count, size_mm, pitch_mm=1.5 * size_mm))

    return build


def _truncated_step(path: Path) -> None:
    text = step_boxes(8)
    path.write_text(text[: len(text) // 2])


def _textjunk_step(path: Path) -> None:
    path.write_text("ISO-10303-21;\nHEADER;\n" + "this is not a STEP entity;\n" * 200)


# ------------------------------------------------------------------------------------------------ nbv2d inputs
def _png(size: int, body: int) -> Callable[[Path], None]:
    def build(path: Path) -> None:
        image = Image.new("L", (size, size), 255)
        if body:
            start = (size - body) // 2
            image.paste(0, (start, start, start + body, start + body))
        image.save(path)

    return build


def _npy_lie(shape: int, data_bytes: int) -> Callable[[Path], None]:
    def build(path: Path) -> None:
        with open(path, "wb") as f:
            np.lib.format.write_array_header_1_0(f, {"descr": "|u1", "fortran_order": False, "shape": (shape, shape)})
            f.write(b"\0" * data_bytes)

    return build


# ------------------------------------------------------------------------------------------ calibration inputs
def _samples(count: int) -> Callable[[Path], None]:
    """``count`` point pairs of the identity transform (robot point = camera point), in the probe's format."""

    def build(path: Path) -> None:
        points = _rng(path.name).uniform(-0.5, 0.5, (count, 3))
        with open(path, "w") as f:
            for i, p in enumerate(points):
                text = "[" + ", ".join(repr(float(x)) for x in p) + "]"
                f.write(f"p_robot 3-DoF index:{i}\n{text}\np_camera 3-DoF index:{i}\n{text}\n")

    return build


def _long_line(path: Path) -> None:
    path.write_text("p_robot 3-DoF index:0\n[" + "0.5, " * 5_000_000 + "0.5]\n")  # a 25 MB line


def _sparse(size: int) -> Callable[[Path], None]:
    def build(path: Path) -> None:
        with open(path, "wb") as f:
            f.truncate(size)  # NUL bytes, sparse on disk

    return build


def _keep(path: Path) -> None:
    path.write_text("KEEP: an existing file no tool may replace without --overwrite\n")


GENERATORS: dict[str, Callable[[Path], None]] = {
    "nope.stl": _absent,
    "garbage.stl": _garbage,
    "garbage.obj": _garbage,
    "garbage.ply": _garbage_ply,
    "garbage.STEP": _garbage,
    "garbage.png": _garbage,
    "truncated.stl": _truncated_stl,
    "count_lie.stl": _count_lie_stl,
    "nan.stl": _nan_stl,
    "huge1e9.stl": _huge_stl,
    "huge1e300.obj": _huge_obj,
    "sphere_s7.stl": _sphere(7),  # 327,680 faces
    "sphere_many.stl": _sphere(8),  # 1,310,720 faces
    "adir.stl": _directory,
    "adir": _directory,
    "devzero.stl": _devzero,
    "fifo.stl": _fifo,
    "box.STEP": _step(1, size_mm=100.0),  # a part the station can scan
    "truncated.STEP": _truncated_step,
    "textjunk.STEP": _textjunk_step,
    "huge_boxes.STEP": _step(16_000),  # ~96,000 B-rep faces
    "big.png": _png(12_000, 2_000),
    "bomb.png": _png(20_000, 0),
    "lie_40k.npy": _npy_lie(40_000, 100),
    "lie_200k.npy": _npy_lie(200_000, 0),
    "good.txt": _samples(12),
    "n250k.txt": _samples(250_000),
    "longline.txt": _long_line,
    "sparse_63M.txt": _sparse(63 * 2**20),
    "sparse_1G.txt": _sparse(2**30),
    "keep.yaml": _keep,
    "keep.json": _keep,
}


def make(folder: Path, name: str) -> Path:
    """The input ``name`` in ``folder``, built on first use."""
    path = Path(folder) / name
    if not os.path.lexists(path):
        GENERATORS[name](path)
    return path
