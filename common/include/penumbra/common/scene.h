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
  Vec3 position;  // world space
  Vec3 normal;    // world space, unit; the side samples at this vertex shade
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

  // Derived by Finalize():
  std::vector<uint32_t> emissiveTriangles;  // triangles whose material emits
  Bounds3 bounds;
  uint64_t identity = 0;  // hash of all that affects shading; the handshake compares it

  const Vec3& Position(uint32_t triangle, int corner) const {
    return vertices[triangles[triangle].v[corner]].position;
  }
  /// Unit geometric normal (counter-clockwise front face).
  Vec3 GeometricNormal(uint32_t triangle) const;
  float Area(uint32_t triangle) const;
  /// Point at barycentrics (b1, b2): (1-b1-b2) p0 + b1 p1 + b2 p2.
  Vec3 PointAt(uint32_t triangle, float b1, float b2) const;
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
  /// not finite, or an index out of range.
  Status Finalize();
};

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
  int32_t AddTexture(Texture texture);
  /// Adds a triangle (counter-clockwise seen from its front). Degenerate
  /// triangles (zero area) are dropped and counted.
  void AddTriangle(const std::array<Vec3, 3>& positions, uint32_t material,
                   const std::array<Vec2, 3>& uv = {});
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

  /// Moves the geometry, materials and textures into `scene` (its lights and
  /// cameras are left alone) and calls scene.Finalize().
  Status BuildInto(Scene& scene);

 private:
  struct Corner {
    Vec3 position;
    Vec2 uv;
  };
  float cosCrease_;
  std::vector<Corner> corners_;      // 3 per triangle
  std::vector<uint32_t> materialOf_; // 1 per triangle
  std::vector<Material> materials_;
  std::vector<Texture> textures_;
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
