#pragma once
// The scene every tier loads: triangles with Lambertian materials, area lights
// (emissive triangles), an optional sun and sky, and camera presets/paths.
//
// Geometry is in world space. Each base triangle is identified by its index
// in Scene::triangles; the renderer's and the SMA's acceleration structures
// and the SMA's subdivision hierarchy all use these indices.
//
// Shading vertices: a Vertex is a point where one shading sample lives. Two
// triangles share a vertex only where the surface is smooth across their
// common corner; at a crease (face normals further apart than the crease
// angle) each side gets its own vertex with its own normal. Texture
// coordinates live on triangle corners, so UV seams never split a vertex.
//
// Movable objects (issue 14). Everything is static unless the scene names
// movable objects. Triangles and vertices are stored static part first, then
// each movable object's in one contiguous range, in the object's own space;
// a RigidTransform per object (ScenePose) places it in the world. For the
// static part object space is world space. Base-triangle indices do not
// change when an object moves; only the pose does.
//
// Static instances (issue 15). A scene file may place many copies of one mesh
// file ("instances"). Each copy is its own shading surface -- its own
// triangles and vertices, in world space, in the static part -- so nothing
// downstream needs to know; StaticInstance records where each copy's ranges
// are, so that the ray tracers can share one acceleration structure among the
// copies of a mesh. Order: the scene's own static triangles, then the
// instances, then the movable objects.

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/rigid_transform.h"

namespace penumbra {

/// An albedo texture, decoded to linear RGB at load time.
struct Texture {
  std::string path;  // for messages
  int width = 0;
  int height = 0;
  std::vector<Rgb> texels;  // row-major; row 0 is the top row of the image file

  /// Bilinear lookup with repeat wrapping. OBJ/glTF-after-import convention:
  /// v = 0 is the bottom row of the image, v = 1 the top.
  Rgb Sample(Vec2 uv) const;
};

struct Material {
  std::string name;
  Rgb albedo{0.8f};            // diffuse reflectance (Kd, glTF baseColorFactor), linear
  int32_t albedoTexture = -1;  // index into Scene::textures, multiplied into albedo; -1: none
  Rgb emission{0.0f};          // radiance emitted from the front face (Ke, glTF emissive)

  bool IsEmissive() const { return emission.r > 0.0f || emission.g > 0.0f || emission.b > 0.0f; }
};

struct Vertex {
  Vec3 position;  // object space: world space for the static part
  Vec3 normal;    // object space, unit; the side samples at this vertex shade
};

struct Triangle {
  std::array<uint32_t, 3> v{};  // Scene::vertices; counter-clockwise seen from the front
  std::array<Vec2, 3> uv{};     // texture coordinates per corner
  uint32_t material = 0;        // Scene::materials
};

/// A distant disc light. Its angular size makes its shadows soft.
struct SunLight {
  Vec3 directionToSun{0.0f, 1.0f, 0.0f};  // world space, unit
  Rgb radiance{0.0f};                     // radiance of the disc
  float angularDiameterRad = 0.00931f;    // the real sun: 0.533 degrees

  float CosHalfAngle() const { return std::cos(0.5f * angularDiameterRad); }
  float SolidAngle() const { return 2.0f * kPi * (1.0f - CosHalfAngle()); }
  /// Irradiance on a surface facing the sun, unoccluded.
  Rgb NormalIrradiance() const { return radiance * SolidAngle(); }
};

/// Radiance arriving from infinitely far away in directions no geometry
/// blocks: a gradient from `ground` (straight down) through `horizon` to
/// `zenith` (straight up). zenith == horizon == ground is a uniform sky.
struct SkyLight {
  Vec3 up{0.0f, 1.0f, 0.0f};
  Rgb zenith{0.0f};
  Rgb horizon{0.0f};
  Rgb ground{0.0f};

  Rgb Radiance(const Vec3& direction) const;
};

/// Where a movable object is at time t of its animation: keyframes with
/// increasing times, the first at t = 0, interpolated by Interpolate().
struct ObjectKeyframe {
  float timeS = 0.0f;
  RigidTransform objectToWorld;
};
struct ObjectAnimation {
  std::vector<ObjectKeyframe> keys;  // at least 2; times strictly increasing, keys[0].timeS == 0
  bool loop = true;                  // false: stays at the last key after it
  double DurationS() const { return keys.empty() ? 0.0 : keys.back().timeS; }
  /// The transform at `timeS` seconds after the animation started (looped
  /// or held at the end).
  RigidTransform At(double timeS) const;
};

/// Names "no movable object": a triangle or vertex of the static part.
inline constexpr uint32_t kStaticObject = ~0u;

/// A rigid part of the scene that may move. Its triangles are
/// Scene::triangles[firstTriangle, firstTriangle + triangleCount) and its
/// vertices Scene::vertices[firstVertex, firstVertex + vertexCount), in
/// object space; triangles refer only to their own object's vertices.
struct MovableObject {
  std::string name;  // unique in the scene; clients pick objects by it
  uint32_t firstTriangle = 0;
  uint32_t triangleCount = 0;
  uint32_t firstVertex = 0;
  uint32_t vertexCount = 0;
  RigidTransform objectToWorld;             // its place when the scene loads
  std::optional<ObjectAnimation> animation; // played by the SMA on its own clock
  Bounds3 objectBounds;                     // derived by Finalize(), object space
};

/// One copy of a mesh file placed by a scene file's "instances" (static, not
/// movable). Its triangles are Scene::triangles[firstTriangle, firstTriangle
/// + triangleCount) and its vertices Scene::vertices[firstVertex, firstVertex
/// + vertexCount), in world space. Every copy of a mesh has the same
/// topology as the first copy (its `prototype`): triangle j of this copy is
/// triangle j of the prototype, with vertex indices offset by the difference
/// of the two firstVertex, and positions meshToWorld * (prototype's
/// positions brought back by its own meshToWorld^-1).
struct StaticInstance {
  uint32_t firstTriangle = 0;
  uint32_t triangleCount = 0;
  uint32_t firstVertex = 0;
  uint32_t vertexCount = 0;
  uint32_t prototype = 0;      // index into Scene::instances of the first copy of the same mesh (itself for it)
  RigidTransform meshToWorld;  // from the mesh file's coordinates to world space
};

struct Scene {
  std::string name;                    // for logs and the handshake
  std::filesystem::path sourcePath;    // the file it was loaded from
  std::vector<Vertex> vertices;
  std::vector<Triangle> triangles;
  std::vector<Material> materials;
  std::vector<Texture> textures;
  std::optional<SunLight> sun;
  std::optional<SkyLight> sky;
  /// Every surface reflects on both of its sides, each shaded on its own
  /// (real models do not keep a consistent winding: a wall may face out of
  /// the room it bounds). Emission stays one-sided, from the front face.
  /// false: only the front face (counter-clockwise) is shaded; its back shows
  /// the front's shading.
  bool twoSided = true;
  std::vector<CameraPreset> cameras;
  std::vector<CameraPath> paths;
  /// Movable objects, in the order their triangle ranges follow the static
  /// part's. Empty: the whole scene is static.
  std::vector<MovableObject> objects;
  /// Static copies of mesh files, in the order of their triangle ranges,
  /// which follow the scene's own static triangles (instances.front()
  /// .firstTriangle) and end at staticTriangleCount. Empty: no instances.
  std::vector<StaticInstance> instances;

  // Derived by Finalize():
  std::vector<uint32_t> emissiveTriangles;  // triangles whose material emits
  Bounds3 bounds;                           // world space, objects at their initial place
  uint32_t staticTriangleCount = 0;         // triangles [0, staticTriangleCount) never move
  uint32_t staticVertexCount = 0;
  uint64_t identity = 0;  // hash of all that affects shading; the handshake compares it

  /// Object-space corner position (world space for static triangles).
  const Vec3& Position(uint32_t triangle, int corner) const {
    return vertices[triangles[triangle].v[corner]].position;
  }
  /// Unit geometric normal (counter-clockwise front face), object space.
  Vec3 GeometricNormal(uint32_t triangle) const;
  float Area(uint32_t triangle) const;
  /// Object-space point at barycentrics (b1, b2): (1-b1-b2) p0 + b1 p1 + b2 p2.
  Vec3 PointAt(uint32_t triangle, float b1, float b2) const;
  /// The movable object a triangle belongs to, or kStaticObject.
  uint32_t ObjectOfTriangle(uint32_t triangle) const;
  /// The movable object a scene vertex belongs to, or kStaticObject.
  uint32_t ObjectOfVertex(uint32_t vertex) const;
  /// Index into `objects` of the object called `name`, or kStaticObject.
  uint32_t FindObject(std::string_view name) const;
  /// Diffuse albedo at a point of a triangle: Kd times the texture at its UV.
  Rgb AlbedoAt(uint32_t triangle, float b1, float b2) const;
  const Material& MaterialOf(uint32_t triangle) const { return materials[triangles[triangle].material]; }
  /// The largest radiance (over colour channels) that any light of the scene
  /// emits: emissive materials, the sun's disc, the sky. No surface of albedo
  /// <= 1 can reflect more than this.
  float MaxEmittedRadiance() const;
  /// Whether anything lights the scene: an emissive triangle, a sun or a
  /// sky. Without any, every sample is black (the loader warns).
  bool HasLight() const { return !emissiveTriangles.empty() || sun.has_value() || sky.has_value(); }
  const CameraPreset* FindCamera(std::string_view name) const;
  const CameraPath* FindPath(std::string_view name) const;

  /// Computes the derived fields after the geometry, materials and lights are
  /// in place. Returns an error for an empty scene, a vertex or normal that is
  /// not finite, an index out of range, or movable objects whose ranges do
  /// not tile the end of the triangle and vertex arrays, that share vertices
  /// with another part, that emit light (moving lights are not supported),
  /// or have duplicate names or invalid animations.
  Status Finalize();

 private:
  Status CheckObjects(const std::string& where);  // part of Finalize(): ranges, names, animations
  Status CheckInstances(const std::string& where);  // part of Finalize(): ranges and shared topology
};

/// Where every movable object is at one scene epoch (issue 14). Epoch 0 is
/// the scene as loaded; the SMA numbers every change after it.
struct ScenePose {
  uint64_t epoch = 0;
  std::vector<RigidTransform> objectToWorld;  // one per Scene::objects

  /// Every object at its MovableObject::objectToWorld, epoch 0.
  static ScenePose Initial(const Scene& scene);
  /// The object-to-world transform of `object` (identity for kStaticObject).
  RigidTransform Of(uint32_t object) const {
    return object == kStaticObject ? RigidTransform::Identity() : objectToWorld[object];
  }
  /// Same places (epochs aside).
  bool SamePlaces(const ScenePose& other) const { return objectToWorld == other.objectToWorld; }
};

/// World-space point and unit geometric normal of a triangle under a pose.
Vec3 WorldPointAt(const Scene& scene, const ScenePose& pose, uint32_t triangle, float b1, float b2);
Vec3 WorldGeometricNormal(const Scene& scene, const ScenePose& pose, uint32_t triangle);
/// World-space bounds of a movable object under a pose.
Bounds3 WorldBounds(const Scene& scene, const ScenePose& pose, uint32_t object);

/// The most textures a scene may have: every tier, and every client that a
/// SceneInfo announces them to, may allocate per texture.
inline constexpr uint32_t kMaxSceneTextures = 1u << 16;

/// Default angle between face normals above which a vertex is split.
inline constexpr float kDefaultCreaseAngleDeg = 40.0f;

/// Collects triangles given by corner positions, welds corners with equal
/// positions into shading vertices and splits them at creases. Loaders and
/// tests both build scenes through it.
class SceneBuilder {
 public:
  explicit SceneBuilder(float creaseAngleDeg = kDefaultCreaseAngleDeg);

  uint32_t AddMaterial(Material material);
  /// Starts a movable object: triangles added from now until the next
  /// BeginObject / EndObject belong to it, in its object space. Corners of
  /// different objects (and of the static part) are never welded together.
  /// Returns the object's index in Scene::objects. The ranges and bounds are
  /// filled in by BuildInto.
  uint32_t BeginObject(MovableObject object);
  /// Triangles added after this belong to the static part again.
  void EndObject() { currentObject_ = kStaticObject; }
  int32_t AddTexture(Texture texture);
  /// Adds a triangle (counter-clockwise seen from its front). Degenerate
  /// triangles (zero area) are dropped and counted.
  void AddTriangle(const std::array<Vec3, 3>& positions, uint32_t material,
                   const std::array<Vec2, 3>& uv = {});
  /// Places a static copy of `mesh` (a scene built from one mesh file by a
  /// SceneBuilder of its own, so welded and crease-split once) at each of
  /// `meshToWorld`. The mesh's materials and textures are added now (once,
  /// however many copies), so that Materials() covers them; its geometry is
  /// copied and transformed by BuildInto, after the builder's own static
  /// triangles and before any movable object (see StaticInstance). Returns
  /// the number of triangles the copies will add.
  size_t AddInstances(Scene mesh, std::span<const RigidTransform> meshToWorld);
  /// Triangles the instances added so far will add.
  size_t InstanceTriangleCount() const { return instanceTriangles_; }
  /// Two triangles: corner, corner+edge1, corner+edge1+edge2, corner+edge2;
  /// front face is on the side of cross(edge1, edge2).
  void AddQuad(const Vec3& corner, const Vec3& edge1, const Vec3& edge2, uint32_t material);
  /// The materials added so far, for loaders that adjust them (a scene
  /// file's overrides) before BuildInto.
  std::span<Material> Materials() { return materials_; }
  size_t DegenerateTriangles() const { return degenerate_; }
  /// Triangles dropped by BuildInto because they repeat an earlier triangle's
  /// corners in the same cyclic order (the same surface listed twice).
  size_t DuplicateTriangles() const { return duplicates_; }
  size_t TriangleCount() const { return corners_.size() / 3; }

  /// Moves the geometry, materials, textures and movable objects into
  /// `scene` (its lights and cameras are left alone; triangles are ordered
  /// static part first, then object by object) and calls scene.Finalize().
  Status BuildInto(Scene& scene);

 private:
  struct Corner {
    Vec3 position;
    Vec2 uv;
  };
  float cosCrease_;
  std::vector<Corner> corners_;      // 3 per triangle
  std::vector<uint32_t> materialOf_; // 1 per triangle
  std::vector<uint32_t> objectOf_;   // 1 per triangle: kStaticObject or an index into objects_
  std::vector<MovableObject> objects_;
  uint32_t currentObject_ = kStaticObject;
  std::vector<Material> materials_;
  std::vector<Texture> textures_;
  void PlaceInstances(Scene& scene, uint32_t staticTriangles, uint32_t staticVertices);
  struct InstancedMesh {
    Scene mesh;  // materials remapped to this builder's
    std::vector<RigidTransform> meshToWorld;
  };
  std::vector<InstancedMesh> instancedMeshes_;
  size_t instanceTriangles_ = 0;
  size_t degenerate_ = 0;
  size_t duplicates_ = 0;
};

struct SceneLoadOptions {
  float creaseAngleDeg = kDefaultCreaseAngleDeg;  // a scene file's crease_angle_deg wins
};

/// Loads a scene from either a scene description (.json, docs/scenes.md) or
/// a mesh file directly (.obj, .gltf, .glb and the other formats assimp
/// reads; lights then come from the mesh's emissive materials only).
/// Any problem -- missing file, malformed mesh, missing texture, non-finite
/// coordinate, empty mesh -- is an Error whose message names the file and
/// the problem. Never throws. Safe to call from several threads at once;
/// logs one summary line per load to the "scene" logger.
Expected<Scene> LoadScene(const std::filesystem::path& path, const SceneLoadOptions& options = {});

}  // namespace penumbra
