"""The run as one USD stage (``--meshes usd``, with the optional ``usd-core`` package: Pixar's
``pxr``), for Blender, Houdini, Omniverse and the other tools that read Universal Scene
Description.

``meshes/animation.usd`` (binary crate) holds, under the default prim ``/World``:

- ``Cloth``: a UsdGeomMesh whose ``points`` (one per particle: the simulated mesh itself, so
  triangles on either side of a UV seam share their vertices, as they do in the simulation) and
  ``normals`` (per vertex: the area-weighted sum of the adjacent triangles' normals,
  normalised, so the shading runs on across a seam) are time-sampled at every frame, with its
  triangles, its UVs as ``primvars:st`` per face corner (faceVarying, indexed: the UVs of the
  seam-split layout of ``Garment.uv_layout`` and each corner's index into them, so a corner on a
  seam takes the side of its own triangle and no triangle's UVs wrap), ``extent`` per frame,
  and a UsdPreviewSurface material that reads the scene's texture (copied beside the file) or
  has the cloth colour;
- ``Body`` (when the scene has one): every collision and display capsule as a UsdGeomCapsule
  (axis Z, its radius and segment length) under an Xform whose translation (the segment's
  midpoint) and orientation (the rotation of +Z onto the segment) are time-sampled.

Stage metadata: up axis Y, 1 metre per unit, time codes = frames at the scene's fps, start and
end = the first and last frame written. One time code per frame, frame k at k/fps seconds.
"""

from pathlib import Path

import numpy as np

from taichi_cloth.errors import InputError
from taichi_cloth.output.files import atomic_path

USD_FILE = "animation.usd"


def import_pxr():
    """The ``pxr`` modules (Usd, UsdGeom, UsdShade, Sdf, Gf, Vt), or an InputError naming the
    package to install."""
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt
    except ImportError:
        raise InputError("--meshes usd: needs the usd-core package (pip install "
                         "usd-core==26.11, or pip install '.[usd]')") from None
    return Usd, UsdGeom, UsdShade, Sdf, Gf, Vt


def vertex_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit normals (V, 3) per vertex: the sum of the adjacent triangles' ½·(p1 − p0) × (p2 −
    p0), normalised (a vertex on no triangle gets +y)."""
    p0, p1, p2 = (points[triangles[:, k]] for k in range(3))
    face = 0.5 * np.cross(p1 - p0, p2 - p0)
    normals = np.zeros_like(points)
    for k in range(3):
        np.add.at(normals, triangles[:, k], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.where(length > 0, normals / np.where(length > 0, length, 1.0), [0.0, 1.0, 0.0])


def rotation_onto(direction: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) that turns +z onto the unit vector ``direction``:
    (1 + z·d, z × d) normalised; a half turn about x when d = −z."""
    w = 1.0 + direction[2]
    if w < 1e-9:
        return (0.0, 1.0, 0.0, 0.0)
    q = np.array([w, -direction[1], direction[0], 0.0])
    q /= np.linalg.norm(q)
    return tuple(float(c) for c in q)


class UsdAnimation:
    """The stage, filled frame by frame (``append``) and written whole by ``finish``."""

    def __init__(self, target: Path, uv_layout, fps: float, color, texture: str = "",
                 body=None):
        """uv_layout: (source particle (V,), uvs (V, 2), triangles (T, 3)) of the cloth's
        seam-split layout (``Garment.uv_layout``): the stage's triangles are the particles'
        (source[triangles]), each corner with the UV of its split vertex; ``texture``: an image
        file name beside ``target`` ("" for the plain ``color``, RGB in [0, 1]); ``body``: the
        scene's ``body.dancer.Body`` or prop (None without one)."""
        Usd, UsdGeom, UsdShade, Sdf, Gf, Vt = self.pxr = import_pxr()
        self.target, self.fps, self.body = Path(target), float(fps), body
        source, uvs, split_triangles = (np.asarray(part) for part in uv_layout)
        self.triangles = source[split_triangles]
        self.stage = stage = Usd.Stage.CreateInMemory()
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        world = UsdGeom.Xform.Define(stage, "/World")
        stage.SetDefaultPrim(world.GetPrim())
        self.mesh = mesh = UsdGeom.Mesh.Define(stage, "/World/Cloth")
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(self.triangles)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(self.triangles.ravel().tolist()))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateDoubleSidedAttr(True)
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(uvs.astype(np.float32)))
        st.SetIndices(Vt.IntArray(split_triangles.ravel().tolist()))
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(
            self._material(texture, color))
        self.capsules = []
        if body is not None:
            UsdGeom.Xform.Define(stage, "/World/Body")
            for index, radius in enumerate(np.concatenate([body.capsule_radius,
                                                           body.display_capsule_radius])):
                holder = UsdGeom.Xform.Define(stage, f"/World/Body/capsule_{index:02d}")
                capsule = UsdGeom.Capsule.Define(stage, f"/World/Body/capsule_{index:02d}/shape")
                capsule.CreateAxisAttr(UsdGeom.Tokens.z)
                capsule.CreateRadiusAttr(float(radius))
                self.capsules.append((holder.AddTranslateOp(), holder.AddOrientOp(),
                                      capsule.CreateHeightAttr()))
        self.frames = []

    def _material(self, texture: str, color):
        """A UsdPreviewSurface: the texture through UsdUVTexture at ``st``, or the colour."""
        Usd, UsdGeom, UsdShade, Sdf, Gf, Vt = self.pxr
        stage = self.stage
        material = UsdShade.Material.Define(stage, "/World/Looks/Cloth")
        surface = UsdShade.Shader.Define(stage, "/World/Looks/Cloth/Surface")
        surface.CreateIdAttr("UsdPreviewSurface")
        surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
        diffuse = surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
        if texture:
            reader = UsdShade.Shader.Define(stage, "/World/Looks/Cloth/UV")
            reader.CreateIdAttr("UsdPrimvarReader_float2")
            reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
            image = UsdShade.Shader.Define(stage, "/World/Looks/Cloth/Texture")
            image.CreateIdAttr("UsdUVTexture")
            image.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(texture))
            image.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
                reader.ConnectableAPI(), "result")
            image.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
            image.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
            diffuse.ConnectToSource(image.ConnectableAPI(), "rgb")
        else:
            diffuse.Set(Gf.Vec3f(*(float(c) for c in color)))
        material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
        return material

    def append(self, frame: int, t: float, positions: np.ndarray) -> None:
        """Frame ``frame`` at time ``t`` [s]: the cloth's particle ``positions`` (N, 3) [m] and
        the body posed at t."""
        Usd, UsdGeom, UsdShade, Sdf, Gf, Vt = self.pxr
        points = np.asarray(positions, np.float32)
        pose = self.body.pose(t) if self.body is not None else None
        self.mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points), frame)
        self.mesh.GetNormalsAttr().Set(Vt.Vec3fArray.FromNumpy(
            vertex_normals(points.astype(np.float64), self.triangles).astype(np.float32)), frame)
        self.mesh.GetExtentAttr().Set(Vt.Vec3fArray.FromNumpy(
            np.stack([points.min(axis=0), points.max(axis=0)])), frame)
        if pose is not None:
            ends_a = np.concatenate([pose.capsule_a, pose.display_capsule_a])
            ends_b = np.concatenate([pose.capsule_b, pose.display_capsule_b])
            for (translate, orient, height), a, b in zip(self.capsules, ends_a, ends_b):
                segment = b - a
                length = float(np.linalg.norm(segment))
                direction = segment / length if length > 0 else np.array([0.0, 0.0, 1.0])
                translate.Set(Gf.Vec3d(*(0.5 * (a + b)).tolist()), frame)
                orient.Set(Gf.Quatf(*rotation_onto(direction)), frame)
                height.Set(length, frame)
        self.frames.append(frame)

    def finish(self) -> None:
        """Write the stage: its time range is the frames appended."""
        self.stage.SetStartTimeCode(min(self.frames))
        self.stage.SetEndTimeCode(max(self.frames))
        with atomic_path(self.target, ".usd") as temporary:
            self.stage.Export(str(temporary))
