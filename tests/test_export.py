"""Exported files: meshes (OBJ with UVs, PLY, VTU, one XDMF series) read back with meshio, the USD
stage with pxr, the PC2 point cache by its byte layout (and, when Blender's Python module is
installed, both in Blender), videos read back with imageio, and writes that leave whole files or
nothing. No window is needed."""

import os
import subprocess
from pathlib import Path

import imageio
import meshio
import numpy as np
import pytest

from taichi_cloth import cli
from taichi_cloth.cli import main
from taichi_cloth.body.dancer import Body
from taichi_cloth.output.files import write_png
from taichi_cloth.output.video import video_writer
from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.config.scene import load_scene
from taichi_cloth.render.surfaces import capsule_template

FRAMES = 3  # simulated; files are written for frames 0 (the start) … FRAMES
WRITTEN = FRAMES + 1
COLUMNS, ROWS = 16, 8
FORMATS = ("obj", "ply", "vtu", "xdmf", "usd", "pc2")


@pytest.fixture(scope="module")
def hula_meshes(tmp_path_factory):
    """``simulate hula`` for 3 small frames with every mesh format and the body; its meshes/."""
    out = tmp_path_factory.mktemp("meshes")
    cli.simulate("hula", [f"cloth.resolution=[{COLUMNS},{ROWS}]"], FRAMES, str(out), None,
                      True, meshes=FORMATS, body_meshes=True)
    return out / "meshes"


def test_every_exporter_writes_the_same_files_from_the_cache(hula_meshes, tmp_path):
    """``render --from-cache DIR --meshes ... --body-meshes``: the meshes exported from the
    cached frames are byte for byte those the run wrote while it simulated."""
    from taichi_cloth.errors import InputError
    try:
        assert cli.main(["render", "--from-cache", str(hula_meshes.parent), "--out",
                         str(tmp_path), "--width", "32", "--height", "24", "--quiet", "--meshes",
                         ",".join(FORMATS), "--body-meshes"]) == 0
    except InputError as error:  # no Vulkan to draw with (CI has it)
        if "Vulkan" in str(error) and not os.environ.get("CI"):
            pytest.skip(str(error))
        raise
    written = sorted(path.relative_to(hula_meshes) for path in hula_meshes.rglob("*")
                     if path.is_file())
    again = tmp_path / "meshes"
    assert sorted(path.relative_to(again) for path in again.rglob("*") if path.is_file()) == \
        written
    for name in written:
        assert (again / name).read_bytes() == (hula_meshes / name).read_bytes(), name


def test_the_vtu_series_has_a_paraview_collection_with_the_frame_times(hula_meshes):
    """cloth.pvd and body.pvd list every frame's VTU file, in order, at k/fps seconds."""
    import xml.etree.ElementTree as ET
    for name in ("cloth", "body"):
        root = ET.parse(hula_meshes / f"{name}.pvd").getroot()
        assert root.get("type") == "Collection"
        datasets = root.find("Collection").findall("DataSet")
        assert [d.get("file") for d in datasets] == [f"{name}_{k:05d}.vtu" for k in range(WRITTEN)]
        assert [float(d.get("timestep")) for d in datasets] == [k / 30 for k in range(WRITTEN)]
        assert all((hula_meshes / d.get("file")).is_file() for d in datasets)


def obj_vertices(path) -> np.ndarray:
    return np.array([[float(c) for c in line.split()[1:4]]
                     for line in path.read_text().splitlines() if line.startswith("v ")])


def test_usd_stage_holds_the_animation(hula_meshes):
    """pxr reads animation.usd: y up, metres, 30 fps from frame 0 to FRAMES; the cloth is the
    simulated mesh: its points at every frame are that frame's PLY points (float32) and its
    triangles the PLY's (the skirt's seam not split: the triangles on either side share their
    vertices, so a self-intersection test on the stage sees no seam), its normals unit, its UVs
    one per face corner (indexed: the seam-split layout's), each the OBJ's UV at that corner
    (the OBJ's faces are in the same order), none wrapping; every capsule's transform carries
    its local segment (0, 0, ±height/2) onto the body's capsule ends at that frame's time."""
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(str(hula_meshes / "animation.usd"))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetFramesPerSecond() == 30
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, FRAMES)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Cloth"))
    assert mesh.GetPointsAttr().GetTimeSamples() == list(range(WRITTEN))
    triangles = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    assert set(mesh.GetFaceVertexCountsAttr().Get()) == {3}
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying
    corner_uvs = np.array(st.ComputeFlattened()).reshape(-1, 3, 2)
    assert corner_uvs.shape == (len(triangles), 3, 2)
    assert len(st.Get()) == COLUMNS * ROWS + ROWS  # one per vertex of the seam-split layout
    assert np.ptp(corner_uvs[..., 0], axis=1).max() < 1.5 / COLUMNS  # no triangle wraps
    obj = meshio.read(hula_meshes / "cloth_00000.obj")
    np.testing.assert_allclose(corner_uvs, obj.point_data["obj:vt"][triangles_of(obj)],
                               atol=1e-6)
    for frame in range(WRITTEN):
        ply = meshio.read(hula_meshes / f"cloth_{frame:05d}.ply")
        assert (triangles == triangles_of(ply)).all()
        points = np.array(mesh.GetPointsAttr().Get(frame))
        np.testing.assert_allclose(points, ply.points, atol=2e-6)
        normals = np.array(mesh.GetNormalsAttr().Get(frame))
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    body = Body("hula")
    pose = body.pose(2 / 30)
    ends = np.concatenate([pose.capsule_a, pose.display_capsule_a]), \
        np.concatenate([pose.capsule_b, pose.display_capsule_b])
    for index in range(body.capsule_count + body.display_capsule_count):
        holder = stage.GetPrimAtPath(f"/World/Body/capsule_{index:02d}")
        capsule = UsdGeom.Capsule(stage.GetPrimAtPath(f"/World/Body/capsule_{index:02d}/shape"))
        matrix = np.array(UsdGeom.Xformable(holder).ComputeLocalToWorldTransform(2))
        half = 0.5 * capsule.GetHeightAttr().Get(2)
        for end, z in ((ends[0][index], -half), (ends[1][index], half)):
            np.testing.assert_allclose(np.array([0.0, 0.0, z, 1.0]) @ matrix, [*end, 1.0],
                                       atol=1e-5)


def test_pc2_point_cache_is_every_frame_of_its_obj(hula_meshes):
    """cloth.pc2 (read by the format's layout: a 12-byte signature, version, count, start,
    rate, samples, float32 points) holds every frame's vertices in cloth.obj's layout."""
    data = (hula_meshes / "cloth.pc2").read_bytes()
    assert data[:12] == b"POINTCACHE2\0"
    version, count = np.frombuffer(data, "<i4", 2, 12)
    start, rate = np.frombuffer(data, "<f4", 2, 20)
    samples = int(np.frombuffer(data, "<i4", 1, 28)[0])
    assert (version, start, rate, samples) == (1, 0.0, 1.0, WRITTEN)
    frames = np.frombuffer(data, "<f4", samples * count * 3, 32).reshape(samples, count, 3)
    assert len(data) == 32 + frames.nbytes
    np.testing.assert_allclose(obj_vertices(hula_meshes / "cloth.obj"), frames[0],
                               atol=2e-6)
    for frame in range(WRITTEN):
        np.testing.assert_allclose(frames[frame],
                                   obj_vertices(hula_meshes / f"cloth_{frame:05d}.obj"),
                                   atol=2e-6)


def test_usd_without_usd_core_is_one_line_exit_2_before_simulating(tmp_path, monkeypatch,
                                                                    capsys):
    import sys
    monkeypatch.setitem(sys.modules, "pxr", None)  # as if usd-core were not installed
    out = tmp_path / "out"
    assert main(["simulate", "sheet", "--frames", "1", "--meshes", "usd", "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert "usd-core" in error and "\n" not in error
    assert not (out / "stats.json").exists()


def test_blender_reads_the_usd_stage_and_the_point_cache(hula_meshes, blender_python):
    result = subprocess.run([str(blender_python), "scripts/check-blender.py", str(hula_meshes)],
                            cwd=blender_python.parents[2], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr


def triangles_of(mesh: meshio.Mesh) -> np.ndarray:
    assert [block.type for block in mesh.cells] == ["triangle"]
    return mesh.cells[0].data


def body_counts() -> tuple[int, int]:
    body = Body("hula")
    direction, _, triangles = capsule_template()
    capsules = body.capsule_count + body.display_capsule_count
    return capsules * len(direction), capsules * len(triangles)


def test_one_file_per_frame_per_format_and_one_series_per_object(hula_meshes):
    names = sorted(p.name for p in hula_meshes.iterdir())
    for name in ("cloth", "body"):
        for file_format in ("obj", "ply", "vtu"):
            assert [n for n in names if n.startswith(f"{name}_") and n.endswith(file_format)] == \
                [f"{name}_{k:05d}.{file_format}" for k in range(WRITTEN)]
        assert f"{name}.xdmf" in names and f"{name}.pvd" in names
    assert {"animation.usd", "cloth.obj", "cloth.pc2"} <= set(names)
    assert "cloth.mtl" in names and "pareo.png" in names
    assert not [n for n in names if n.startswith(".")]  # no temporary file left


@pytest.mark.parametrize("file_format", ["ply", "vtu"])
def test_cloth_and_body_meshes_read_back_with_their_counts(hula_meshes, file_format):
    particles, triangles = COLUMNS * ROWS, 2 * COLUMNS * (ROWS - 1)
    body_vertices, body_triangles = body_counts()
    for frame in range(WRITTEN):
        cloth = meshio.read(hula_meshes / f"cloth_{frame:05d}.{file_format}")
        assert cloth.points.shape == (particles, 3) and np.isfinite(cloth.points).all()
        assert triangles_of(cloth).shape == (triangles, 3)
        body = meshio.read(hula_meshes / f"body_{frame:05d}.{file_format}")
        assert body.points.shape == (body_vertices, 3) and np.isfinite(body.points).all()
        assert triangles_of(body).shape == (body_triangles, 3)


def test_obj_carries_uvs_with_the_seam_column_duplicated(hula_meshes):
    path = hula_meshes / "cloth_00002.obj"
    mesh = meshio.read(path)
    assert mesh.points.shape == (COLUMNS * ROWS + ROWS, 3) and np.isfinite(mesh.points).all()
    triangles = triangles_of(mesh)
    assert triangles.shape == (2 * COLUMNS * (ROWS - 1), 3)
    uv = mesh.point_data["obj:vt"]
    assert uv.shape == (len(mesh.points), 2) and uv.min() >= 0 and uv.max() <= 1
    assert np.ptp(uv[triangles][..., 0], axis=1).max() < 1.5 / COLUMNS  # no triangle wraps
    text = path.read_text()
    assert "mtllib cloth.mtl" in text and "\nf 1/1 " in text  # faces reference their UVs
    # the copies (the seam column's particles) are said at the top
    assert text.splitlines()[1].startswith(
        f"# {ROWS} of these {COLUMNS * ROWS + ROWS} vertices repeat a particle at a UV seam")
    seam_copies = mesh.points[COLUMNS * ROWS:]
    np.testing.assert_array_equal(seam_copies, mesh.points[:COLUMNS * ROWS:COLUMNS])
    assert "map_Kd pareo.png" in (hula_meshes / "cloth.mtl").read_text()


def test_xdmf_series_has_one_step_per_frame_with_moving_geometry(hula_meshes):
    fps = load_scene("hula").scene.fps
    with meshio.xdmf.TimeSeriesReader(hula_meshes / "cloth.xdmf") as reader:
        assert reader.num_steps == WRITTEN
        points, cells = reader.read_points_cells()
        assert points.shape == (COLUMNS * ROWS, 3) and cells[0].data.shape[0] == 2 * COLUMNS * (ROWS - 1)
        times = [reader.read_data(k)[0] for k in range(WRITTEN)]
    np.testing.assert_allclose(times, np.arange(WRITTEN) / fps)
    last = meshio.read(hula_meshes / f"cloth_{FRAMES:05d}.vtu").points
    np.testing.assert_allclose(points, meshio.read(hula_meshes / "cloth_00000.vtu").points,
                               atol=1e-5)
    assert not np.allclose(points, last)
    with meshio.xdmf.TimeSeriesReader(hula_meshes / "body.xdmf") as reader:
        assert reader.num_steps == WRITTEN
        assert reader.read_points_cells()[0].shape == (body_counts()[0], 3)


def test_xdmf_heavy_data_is_every_frames_geometry_in_hdf5(hula_meshes):
    """Each step's Geometry points into cloth.h5 (h5py) at that frame's vertices (its VTU's),
    all steps share one topology dataset, and no heavy data sits in the XML."""
    import xml.etree.ElementTree as ET
    import h5py
    root = ET.parse(hula_meshes / "cloth.xdmf").getroot()
    grids = root.find("Domain").find("Grid").findall("Grid")
    assert len(grids) == WRITTEN
    with h5py.File(hula_meshes / "cloth.h5", "r") as data:
        for frame, grid in enumerate(grids):
            items = {tag: grid.find(tag).find("DataItem") for tag in ("Topology", "Geometry")}
            assert all(item.get("Format") == "HDF" for item in items.values())
            assert items["Topology"].text == "cloth.h5:/topology"
            path = items["Geometry"].text.split(":", 1)[1]
            np.testing.assert_allclose(
                data[path][()], meshio.read(hula_meshes / f"cloth_{frame:05d}.vtu").points,
                atol=1e-6)
    assert (hula_meshes / "cloth.xdmf").stat().st_size < 200 + 600 * WRITTEN  # references only


def test_uv_layout_of_a_sheet_changes_nothing():
    scene = load_scene("sheet", ("cloth.resolution=[5,4]",))
    garment = build_garment(scene.cloth, scene.material, None, scene.path)
    source, uvs, triangles = garment.uv_layout()
    np.testing.assert_array_equal(source, np.arange(20))
    np.testing.assert_array_equal(triangles, garment.triangles)
    assert uvs is garment.uvs


@pytest.mark.parametrize("video_format", ["mp4", "gif"])
def test_video_reads_back_with_its_frames_and_even_size(tmp_path, video_format):
    target = tmp_path / f"clip.{video_format}"
    ramp = np.linspace(0, 255, 33 * 25 * 3).reshape(25, 33, 3).astype(np.uint8)
    with video_writer(target, video_format, fps=12) as append:
        for k in range(5):
            append(np.roll(ramp, 3 * k, axis=1))
    frames = imageio.v2.mimread(target)
    assert len(frames) == 5
    expected = (24, 32) if video_format == "mp4" else (25, 33)
    assert frames[0].shape[:2] == expected
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]


def top_level_boxes(path) -> list[str]:
    """The types of an MP4 file's top-level boxes in file order (ISO/IEC 14496-12 §4.2: each
    box starts with a 32-bit big-endian size, then its 4-character type; size 1: a 64-bit size
    follows)."""
    data, types, offset = path.read_bytes(), [], 0
    while offset + 8 <= len(data):
        size = int.from_bytes(data[offset:offset + 4], "big")
        types.append(data[offset + 4:offset + 8].decode("latin-1"))
        if size == 1:
            size = int.from_bytes(data[offset + 8:offset + 16], "big")
        offset += size if size else len(data)
    return types


def test_mp4_starts_fast_and_keeps_its_frame_rate(tmp_path):
    """The index (moov) comes before the frames (mdat), and ffmpeg reads 30 fps back."""
    target = tmp_path / "clip.mp4"
    with video_writer(target, "mp4", fps=30) as append:
        for k in range(4):
            append(np.full((16, 16, 3), 60 * k, np.uint8))
    boxes = top_level_boxes(target)
    assert "moov" in boxes and "mdat" in boxes and boxes.index("moov") < boxes.index("mdat")
    assert imageio.v3.immeta(target, plugin="FFMPEG")["fps"] == pytest.approx(30.0)


def test_an_interrupted_video_or_frame_leaves_no_file(tmp_path, monkeypatch):
    target = tmp_path / "clip.mp4"
    with pytest.raises(KeyboardInterrupt):
        with video_writer(target, "mp4", fps=30) as append:
            append(np.zeros((16, 16, 3), np.uint8))
            raise KeyboardInterrupt

    def half_written(path, image):
        Path(path).write_bytes(b"\x89PNG half")
        raise KeyboardInterrupt

    monkeypatch.setattr("taichi_cloth.output.files.iio.imwrite", half_written)
    with pytest.raises(KeyboardInterrupt):
        write_png(tmp_path / "frame.png", np.zeros((4, 4, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, flag", [
    (["render", "hula", "--meshes", "obj,stl"], "--meshes"),
    (["simulate", "hula", "--meshes", ""], "--meshes"),
    (["render", "hula", "--video", "avi"], "--video"),
])
def test_bad_output_flags_exit_2_naming_the_flag(argv, flag, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    message = capsys.readouterr().err.strip()
    assert len(message.splitlines()) == 1 and flag in message


def test_stale_frames_of_a_longer_run_are_removed(tmp_path):
    """A shorter run removes the meshes a longer one wrote there (its manifest lists them)."""
    meshes = tmp_path / "meshes"
    for frames in (3, 1):
        cli.simulate("skirt", ["cloth.resolution=[6,3]"], frames, str(tmp_path), None, True,
                     meshes=("ply",))
    assert sorted(p.name for p in meshes.iterdir()) == ["cloth_00000.ply", "cloth_00001.ply"]
    assert Path(tmp_path / "stats.json").exists()


def test_seam_comment_counts_the_copies_wherever_they_are():
    """A mesh garment's layout repeats a seam's particles among the others (one vertex per
    distinct particle and UV): the comment counts the copies and the particles, and a layout
    without copies has none."""
    from taichi_cloth.output.meshes import seam_comment
    assert seam_comment(np.array([0, 1, 1, 2, 2, 2, 3])) == (
        "# 3 of these 7 vertices repeat a particle at a UV seam, for its other UVs (the "
        "simulated mesh has 4): weld coincident vertices before testing for "
        "self-intersections\n")
    assert seam_comment(np.arange(5)) == ""
