"""Cloth and body meshes per frame: OBJ with UVs and a material, PLY and VTU through meshio, and
one XDMF time series per object (ParaView, Blender's importers)."""

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import meshio
import numpy as np

from taichi_cloth.output.files import atomic_path


def obj_lines(template: str, values: np.ndarray) -> str:
    """One ``template`` line per row of ``values``, formatted in one go (a single %-format of
    the repeated template: ~4× faster than ``numpy.savetxt``, the same text)."""
    return (template * len(values)) % tuple(values.ravel().tolist())


def obj_topology(triangles: np.ndarray, uvs=None) -> str:
    """An OBJ's vt and f lines: faces ``f v/vt`` when ``uvs`` (V, 2) are given (meshio's own
    writer leaves faces without them, so UVs are lost on import), else ``f v``. The same for
    every frame of a series, so ``MeshSeries`` formats them once."""
    faces = np.asarray(triangles) + 1
    if uvs is None:
        return obj_lines("f %d %d %d\n", faces)
    return obj_lines("vt %.6f %.6f\n", np.asarray(uvs)) + \
        obj_lines("f %d/%d %d/%d %d/%d\n", np.repeat(faces, 2, axis=1))


def seam_comment(source: np.ndarray) -> str:
    """An OBJ comment line saying how many vertices of a seam-split layout (``source``: each
    vertex's particle, ``Garment.uv_layout``) repeat a particle for its other UVs, "" when none
    does: a self-intersection test on the file must weld them (the triangles on either side of
    the seam meet there without sharing a vertex index)."""
    source = np.asarray(source)
    _, first = np.unique(source, return_index=True)
    copies = np.setdiff1d(np.arange(len(source)), first)
    if not len(copies):
        return ""
    return (f"# {len(copies)} of these {len(source)} vertices repeat a particle at a UV seam, "
            f"for its other UVs (the simulated mesh has {len(first)}): weld coincident "
            f"vertices before testing for self-intersections\n")


def write_obj(target: Path, points: np.ndarray, topology: str, material: str = "",
              note: str = "") -> None:
    """A Wavefront OBJ, atomically: v lines of ``points`` and the ``topology`` text
    (``obj_topology``), with ``mtllib <material>.mtl`` + ``usemtl <material>`` when
    ``material`` is named, after the ``note`` (comment lines, ``seam_comment``)."""
    header = "# taichi_cloth\n" + note + (f"mtllib {material}.mtl\nusemtl {material}\n"
                                          if material else "")
    with atomic_path(target) as temporary:
        temporary.write_text(header + obj_lines("v %.6f %.6f %.6f\n", np.asarray(points))
                             + topology, encoding="utf-8")


def write_material(target: Path, name: str, color, texture: str = "") -> None:
    """An OBJ material library with one material: diffuse ``color`` or the image ``texture``
    (a file name beside it)."""
    text = f"newmtl {name}\nKa 0 0 0\nKs 0 0 0\n"
    text += "Kd 1 1 1\nmap_Kd " + texture + "\n" if texture else \
        "Kd {:.4f} {:.4f} {:.4f}\n".format(*color)
    with atomic_path(target) as temporary:
        temporary.write_text(text, encoding="utf-8")


PLY_TIMESTAMP = re.compile(rb"^(comment Created by meshio v[^,\n]*), [^\n]*\n", re.MULTILINE)


def write_meshio(target: Path, points: np.ndarray, triangles: np.ndarray, file_format: str):
    """A triangle mesh through meshio (``ply``: binary; ``vtu``: compressed XML), atomically.
    meshio stamps a PLY header with the current time; the stamp is dropped so that identical
    runs write identical files."""
    with atomic_path(target) as temporary:
        meshio.write(temporary, meshio.Mesh(points, [("triangle", triangles)]),
                     file_format=file_format)
        if file_format == "ply":
            temporary.write_bytes(PLY_TIMESTAMP.sub(rb"\1\n", temporary.read_bytes(), count=1))


class XdmfSeries:
    """One moving triangle mesh as an XDMF 3 file for ParaView (``<name>.xdmf``) with its heavy
    data in HDF5 beside it (``<name>.h5``: the triangles at ``/topology``, each frame's
    vertices as float32 at ``/points/frame_NNNNN``, gzip-compressed, without timestamps so
    that identical runs write identical bytes): a temporal collection of one uniform grid per
    frame, each with its time [s], the shared topology and its own geometry. (meshio's
    ``TimeSeriesWriter`` keeps one geometry for all steps, which cannot show cloth moving.)
    The frames are gathered in memory and both files written whole by ``write``."""

    def __init__(self, target: Path, triangles: np.ndarray):
        self.target = Path(target)
        self.triangles = np.asarray(triangles, dtype=np.int32)
        self.frames = []  # (frame, t [s], points (V, 3) float32)

    def append(self, frame: int, t: float, points: np.ndarray) -> None:
        self.frames.append((frame, float(t), np.asarray(points, dtype=np.float32)))

    def write(self) -> None:
        import h5py
        heavy = self.target.with_suffix(".h5")
        with atomic_path(heavy) as temporary:
            with h5py.File(temporary, "w", track_order=True) as data:
                data.create_dataset("topology", data=self.triangles, track_times=False)
                group = data.create_group("points", track_order=True)
                for frame, _, points in self.frames:
                    group.create_dataset(f"frame_{frame:05d}", data=points, compression="gzip",
                                         compression_opts=4, track_times=False)
        root = ET.Element("Xdmf", Version="3.0")
        collection = ET.SubElement(ET.SubElement(root, "Domain"), "Grid",
                                   Name=self.target.stem, GridType="Collection",
                                   CollectionType="Temporal")
        for frame, t, points in self.frames:
            grid = ET.SubElement(collection, "Grid", Name=f"frame_{frame:05d}", GridType="Uniform")
            topology = ET.SubElement(grid, "Topology", TopologyType="Triangle",
                                     NumberOfElements=str(len(self.triangles)))
            topology.append(hdf_item(f"{heavy.name}:/topology", self.triangles.shape, "Int"))
            geometry = ET.SubElement(grid, "Geometry", GeometryType="XYZ")
            geometry.append(hdf_item(f"{heavy.name}:/points/frame_{frame:05d}", points.shape,
                                     "Float"))
            ET.SubElement(grid, "Time", Value=repr(t))
        tree = ET.ElementTree(root)
        ET.indent(tree, space=" ")
        with atomic_path(self.target) as temporary:
            tree.write(temporary, encoding="utf-8", xml_declaration=True)


def hdf_item(reference: str, shape: tuple, number_type: str) -> ET.Element:
    """An XDMF DataItem that points at an HDF5 dataset (``file.h5:/path``) of 4-byte numbers."""
    item = ET.Element("DataItem", Dimensions=" ".join(map(str, shape)), NumberType=number_type,
                      Precision="4", Format="HDF")
    item.text = reference
    return item


def write_pvd(target: Path, datasets: list[tuple[float, str]]) -> None:
    """A ParaView collection (``.pvd``) of (time [s], file name beside it) datasets, in order:
    opening it in ParaView loads the VTU series as one animation with those times."""
    root = ET.Element("VTKFile", type="Collection", version="0.1")
    collection = ET.SubElement(root, "Collection")
    for t, name in datasets:
        ET.SubElement(collection, "DataSet", timestep=repr(float(t)), part="0", file=name)
    tree = ET.ElementTree(root)
    ET.indent(tree, space=" ")
    with atomic_path(target) as temporary:
        tree.write(temporary, encoding="utf-8", xml_declaration=True)


class MeshSeries:
    """One object's meshes, frame after frame, in each of ``formats`` under ``directory``:
    ``<name>_00000.obj|ply|vtu`` per frame, and for the run (written by ``finish``)
    ``<name>.xdmf`` and, with VTU, the collection ``<name>.pvd`` of every frame from 0 (a
    resumed run lists the earlier ones it finds on disk, frame k at k/``fps`` s).
    ``uv_layout`` = (source (V',), uvs (V', 2), triangles) from ``Garment.uv_layout`` gives the
    OBJ files texture coordinates, the material ``<name>.mtl`` and the comment on the seam's
    copies (``seam_comment``)."""

    def __init__(self, directory: Path, name: str, formats, triangles: np.ndarray,
                 uv_layout=None, material: bool = False, fps: float = 30.0):
        self.directory, self.name, self.formats = Path(directory), name, tuple(formats)
        self.triangles = np.asarray(triangles)
        self.uv_layout = uv_layout
        self.material = name if material else ""
        self.series = XdmfSeries(self.directory / f"{name}.xdmf", self.triangles) \
            if "xdmf" in self.formats else None
        self.fps = fps
        self.appended = set()  # the frames this run wrote
        if "obj" in self.formats:
            self.obj_topology = obj_topology(*(uv_layout[2], uv_layout[1]) if uv_layout
                                             else (self.triangles,))
            self.obj_note = seam_comment(uv_layout[0]) if uv_layout else ""

    def append(self, frame: int, t: float, points: np.ndarray) -> None:
        """The meshes of ``frame`` at simulated time ``t`` [s], vertex positions ``points`` [m]."""
        stem = self.directory / f"{self.name}_{frame:05d}"
        for file_format in self.formats:
            if file_format == "obj":
                shown = points[self.uv_layout[0]] if self.uv_layout is not None else points
                write_obj(stem.with_suffix(".obj"), shown, self.obj_topology, self.material,
                          self.obj_note)
            elif file_format in ("ply", "vtu"):
                write_meshio(stem.with_suffix(f".{file_format}"), points, self.triangles,
                             file_format)
        if self.series is not None:
            self.series.append(frame, t, points)
        self.appended.add(frame)

    def finish(self) -> None:
        if self.series is not None:
            self.series.write()
        if "vtu" in self.formats and self.appended:
            first = min(self.appended)
            earlier = {int(path.stem.rsplit("_", 1)[1])
                       for path in self.directory.glob(f"{self.name}_[0-9]*.vtu")}
            frames = sorted({k for k in earlier if k < first} | self.appended)
            write_pvd(self.directory / f"{self.name}.pvd",
                      [(k / self.fps, f"{self.name}_{k:05d}.vtu") for k in frames])
