#pragma once
// Scene description files (.json, documented in docs/scenes.md): which mesh
// to load and what to add to it. Private to penumbra_scene_io; LoadScene is
// the public entry.

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/scene.h"

namespace penumbra {

/// Replaces parts of a mesh material, found by name.
struct MaterialOverride {
  std::string name;
  std::optional<Rgb> albedo;
  std::optional<Rgb> emission;
};

/// A one-sided emitting parallelogram, added to the scene as two triangles:
/// corner, corner + edge1, corner + edge1 + edge2, corner + edge2, emitting
/// toward cross(edge1, edge2).
struct QuadLight {
  std::string name;  // also the name of its material
  Vec3 corner{0.0f};
  Vec3 edge1{0.0f};
  Vec3 edge2{0.0f};
  Rgb radiance{0.0f};
};

/// Bounds on a scene file's "objects" (issue 14): each object costs every
/// tier an instance and every client a transform, and each is read from the
/// file before anything checks the mesh.
inline constexpr size_t kMaxSceneObjects = 256;
inline constexpr size_t kMaxObjectGroups = 256;        // names in one object's "group"
inline constexpr size_t kMaxObjectKeyframes = 10'000;  // keys in one object's "animation"
inline constexpr size_t kMaxObjectNameBytes = 128;
inline constexpr float kMaxKeyframeTimeS = 1e6f;

/// A movable object named under "objects" (docs/scenes.md). Exactly one of
/// `groups` (parts of the main mesh, by assimp node name) and `meshPath` (a
/// mesh file of its own) is set.
///
/// Frames. A mesh-file object's object space is its file's own coordinates.
/// A group's object space has world axes and its origin at `pivot` (default:
/// the centre of the group's world bounding box, known once the mesh is
/// read): object-space vertex = world vertex - pivot. `placement` and every
/// keyframe are given relative to the object's home frame, identity for a
/// mesh file and translate(pivot) for a group, so that the object-to-world
/// transform is home * placement (home * key), and a rotation in the file
/// turns a group about its pivot.
struct ObjectDescription {
  std::string name;                   // the key under "objects"
  std::vector<std::string> groups;    // "group": one name or a list
  std::filesystem::path meshPath;     // "mesh", resolved against the scene file's folder
  std::optional<Vec3> pivot;          // "pivot" (groups only), world space
  RigidTransform placement;           // "transform"; the first keyframe when animated
  std::optional<ObjectAnimation> animation;  // keys relative to the home frame, like `placement`
};

/// Bounds on a scene file's "instances" (issue 15): each copy costs every
/// tier its triangles and vertices, so the copies' count and their total
/// triangle count (with the scene's own) are checked before any is made.
inline constexpr size_t kMaxSceneInstances = 4096;
inline constexpr size_t kMaxSceneTriangles = size_t(1) << 24;  // 16.7 million

/// A static copy of a mesh file placed by "instances" (docs/scenes.md).
struct InstanceDescription {
  std::filesystem::path meshPath;  // "mesh", resolved against the scene file's folder
  RigidTransform meshToWorld;      // "transform"; identity when absent
};

/// A parsed and validated scene file. Paths are resolved against the folder
/// of the scene file; camera paths given as files are already read.
struct SceneDescription {
  std::filesystem::path sourcePath;  // the scene file
  std::string name;                  // "name", or the file's stem
  std::filesystem::path meshPath;
  std::optional<float> creaseAngleDeg;
  float emissionScale = 1.0f;  // multiplies the mesh's own emission
  bool twoSided = true;        // "two_sided": surfaces reflect on both sides
  std::vector<MaterialOverride> materialOverrides;
  std::vector<QuadLight> quadLights;
  std::optional<SunLight> sun;
  std::optional<SkyLight> sky;
  std::vector<CameraPreset> cameras;  // in file order
  std::vector<CameraPath> paths;      // in file order
  std::vector<ObjectDescription> objects;  // in file order
  std::vector<InstanceDescription> instances;  // in file order
};

/// Reads and validates a scene file. Every error names the file and, where
/// there is one, the offending key ("scenes/x.json: sun: unknown key
/// \"irradience\"").
Expected<SceneDescription> ParseSceneFile(const std::filesystem::path& path);

/// Applies the description's emission scale to the mesh materials already in
/// `builder`, adds its quad lights, then applies its material overrides (to
/// every material of that name: the main mesh's, the instanced meshes', a
/// quad's). An override that names no material is an error.
Status ApplyToBuilder(const SceneDescription& description, SceneBuilder& builder);

}  // namespace penumbra
