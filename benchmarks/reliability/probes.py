"""The probe catalogue: one :class:`Probe` per row of the reliability probe's tables that a command line can replay.

A probe names its id (the probe's row), the tool (a script of ``scripts/``), its arguments, the inputs it needs
(built by :mod:`.inputs`), what it should end with (``refuse``, ``succeed``, ``either``), which bound of the
conditions applies (``refusal``, ``planning``, ``scheduler``, ``run``), and optional checks: a regular expression the
error must match, expressions that must not be printed, a file that must be left unchanged, extra environment.

Arguments are templates: ``{in}`` is the inputs folder, ``{out}`` the probe's own output folder, ``{http_port}`` and
``{silent_port}`` the ports of the runner's fake schedulers (an HTTP server; a listener that never answers),
``{closed_port}`` a port nobody listens on, ``{T}`` the planning time limit of the conditions.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CLI_PROBES", "Probe"]


@dataclass(frozen=True)
class Probe:
    id: str
    tool: str
    args: tuple[str, ...]
    what: str
    inputs: tuple[str, ...] = ()
    ends: str = "refuse"
    bound: str = "refusal"
    message: str = ""
    forbid: tuple[str, ...] = ()
    unchanged: str = ""  # an input that must keep its content
    env: tuple[tuple[str, str], ...] = ()


PLAN = "plan_measurement.py"
RECON = "reconstruct.py"
NBV2D = "nbv2d.py"
CAL = "calibrate.py"

_PLAN_OUT = ("--time-limit", "{T}", "--output-dir", "{out}", "-q")
_RECON_OUT = ("--max-views", "1", "--pixel-step", "8", "--no-ground-truth", "--out", "{out}/rec")
_NBV2D_OUT = ("--script", "fullpix", "--out", "{out}/nbv2d")
_CORRUPT = r"corrupt|cannot read|not a|unreadable|invalid|malformed|truncated|broken"


CUBE = "{root}/parts/objectA_wuerfel.stl"


def _plan(id, part, what, *extra, **kw) -> Probe:
    """``part`` an input's name, or ``CUBE``."""
    inputs = () if part == CUBE else (part,)
    path = part if part == CUBE else f"{{in}}/{part}"
    return Probe(id, PLAN, (path, *_PLAN_OUT, *extra), what, inputs=(*inputs, *kw.pop("inputs", ())), **kw)


def _recon(id, part, what, *extra, out=_RECON_OUT, **kw) -> Probe:
    """``part`` an input's name (with a dot) or a procedural shape (``cup``)."""
    inputs = (part,) if "." in part else ()
    path = f"{{in}}/{part}" if inputs else part
    return Probe(id, RECON, (path, *out, *extra), what, inputs=(*inputs, *kw.pop("inputs", ())), **kw)


def _nbv2d(id, image, what, *extra, **kw) -> Probe:
    source = ("--object-image", f"{{in}}/{image}") if image else ("--object", "disc")
    return Probe(id, NBV2D, (*source, *_NBV2D_OUT, *extra), what, inputs=(image,) if image else (), **kw)


def _cal(id, data, what, *extra, **kw) -> Probe:
    return Probe(id, CAL, (f"{{in}}/{data}", *extra), what, inputs=(data, *kw.pop("inputs", ())), **kw)


CLI_PROBES: tuple[Probe, ...] = (
    # plan_measurement.py
    _plan("P1", "nope.stl", "missing part file", message="not found|does not exist"),
    _plan("P4", "garbage.stl", "4 kB random bytes as STL", message=_CORRUPT),
    _plan("P5", "garbage.obj", "4 kB random bytes as OBJ", message=_CORRUPT),
    _plan("P6", "garbage.ply", "PLY header claiming 1e9 vertices", message=_CORRUPT + "|PLY"),
    _plan("P7", "garbage.STEP", "random bytes as STEP", message=_CORRUPT + "|STEP"),
    _plan("P8", "textjunk.STEP", "STEP header, text junk", message=_CORRUPT + "|STEP"),
    _plan("P9", "truncated.STEP", "first half of a STEP file", message=_CORRUPT + "|STEP"),
    _plan("P11", "truncated.stl", "half a binary STL", message=_CORRUPT + "|length|triangles"),
    _plan("P12", "count_lie.stl", "binary STL claiming 2^32-1 triangles", message=_CORRUPT + "|triangles"),
    _plan("P13", "nan.stl", "one vertex NaN", message="NaN|finite"),
    _plan("P18", "adir.stl", "a directory as part", message="directory"),
    _plan("P19", "devzero.stl", "/dev/zero as part", message="regular file|device"),
    _plan("P20", "fifo.stl", "a FIFO as part", message="regular file|fifo"),
    _plan("P21", "huge1e9.stl", "cube of 1e9 mm", "--place", "fixture"),
    _plan("P22", "huge1e300.obj", "vertices at +-5e299", message="overflow|too large|finite|extent|plausib"),
    _plan("P24", "sphere_s7.stl", "icosphere, 327,680 faces", ends="succeed", bound="planning"),
    _plan("P25", "sphere_many.stl", "icosphere, 1,310,720 faces", ends="either", bound="planning"),
    _plan(
        "P27",
        "huge_boxes.STEP",
        "STEP of 16,000 boxes (~110 MB)",
        "--place",
        "fixture",
        ends="either",
        bound="planning",
    ),
    _plan("P29", CUBE, "--time-limit nan", "--time-limit", "nan", message="time.limit"),
    _plan("P31", CUBE, "--workers 1000", "--workers", "1000", message="workers"),
    _plan("P32", CUBE, "--workers 64 on the cube", "--workers", "64", ends="either", bound="planning"),
    _plan(
        "P36",
        CUBE,
        "--scheduler at an HTTP server",
        "--scheduler",
        "tcp://127.0.0.1:{http_port}",
        bound="scheduler",
        message="scheduler",
    ),
    _plan(
        "P37",
        CUBE,
        "--scheduler at a silent listener",
        "--scheduler",
        "tcp://127.0.0.1:{silent_port}",
        bound="scheduler",
        message="scheduler",
    ),
    _plan("P38", CUBE, "--max-memory 0.001", "--max-memory", "0.001", message="memory"),
    _plan("P40", CUBE, "--density 1000", "--density", "1000", message="budget|samples"),
    # reconstruct.py
    _recon("C1", "nope.stl", "missing part file", message="not found|does not exist"),
    _recon("C2", "garbage.stl", "4 kB random bytes as STL", message=_CORRUPT),
    _recon("C3", "truncated.STEP", "first half of a STEP file", message=_CORRUPT + "|STEP"),
    _recon("C4", "nan.stl", "one vertex NaN", message="NaN|finite"),
    _recon("C5", "devzero.stl", "/dev/zero as part", message="regular file|device"),
    _recon("C6", "huge1e9.stl", "cube of 1e9 mm", message="extent|large|plausib"),
    _recon("C7", "huge1e300.obj", "vertices at +-5e299", message="overflow|too large|finite|extent|plausib"),
    _recon(
        "C9",
        "box.STEP",
        "STEP in the file's own unit (mm)",
        ends="succeed",
        bound="run",
        forbid=(r"extent 0 mm", r"Chamfer inf"),
    ),
    _recon("C12", "cup", "--resolution 0.0005 (175 M voxels)", "--resolution", "0.0005", message="voxels"),
    _recon("C14a", "cup", "--out under /proc", out=(*_RECON_OUT[:-1], "/proc/evil")),
    _recon(
        "C14b",
        "cup",
        "--summary an existing folder",
        "--summary",
        "{in}/adir",
        inputs=("adir",),
        message="directory|folder",
    ),
    _recon(
        "U4",
        "cup",
        "--summary onto an existing file",
        "--summary",
        "{in}/keep.json",
        inputs=("keep.json",),
        message="exists|overwrite",
        unchanged="keep.json",
    ),
    # nbv2d.py
    _nbv2d("B1a", "garbage.png", "4 kB random bytes as PNG", message="PNG|" + _CORRUPT),
    _nbv2d("B1b", "lie_40k.npy", ".npy header 40000x40000, 100 bytes of data"),
    _nbv2d("B2", "lie_200k.npy", ".npy header 200000x200000 (37 GB)"),
    _nbv2d("B3", "", "--rf-length 1e308", "--rf-length", "1e308", message="rf.length"),
    _nbv2d("B5", "big.png", "PNG 12000x12000, 168 kB"),
    _nbv2d("B6", "bomb.png", "uniform PNG 20000x20000"),
    # calibrate.py
    _cal("K1", "good.txt", "12 good samples", "-o", "{out}/cal.yaml", ends="succeed"),
    _cal("K7", "longline.txt", "one 25 MB line", message="line"),
    _cal("K8", "sparse_63M.txt", "63 MB of NUL bytes (under the size cap)"),
    _cal("K9", "sparse_1G.txt", "1 GB sparse file", message="bytes|size|large"),
    _cal("K11", "n250k.txt", "250,000 samples, 1e6 lines (45 MB)", "-o", "{out}/cal.yaml", ends="either", bound="data"),
    _cal(
        "U3",
        "good.txt",
        "-o onto an existing file",
        "-o",
        "{in}/keep.yaml",
        inputs=("keep.yaml",),
        message="exists|overwrite",
        unchanged="keep.yaml",
    ),
    # measure.py
    Probe(
        "M1",
        "measure.py",
        ("--part", "{root}/parts/objectA_wuerfel.stl"),
        "no ROS master (closed port)",
        message="master",
        env=(("ROS_MASTER_URI", "http://127.0.0.1:{closed_port}"),),
    ),
)
