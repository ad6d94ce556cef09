#pragma once
// Mesh files (OBJ/MTL, glTF, GLB and whatever else assimp reads) into a
// SceneBuilder. Private to penumbra_scene_io; LoadScene is the public entry.

#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/scene.h"

namespace penumbra {

/// Reads `meshPath` with assimp, flattens its node hierarchy into world space
/// and adds every triangle (corner positions and UVs) to `builder`, which
/// welds and crease-splits them. Only materials some triangle uses are added:
/// albedo = diffuse colour (glTF baseColorFactor) times the diffuse/base-colour
/// texture, decoded to linear RGB; emission = emissive colour times the
/// emissive intensity (KHR_materials_emissive_strength). Each texture file or
/// embedded image is decoded once however many materials use it.
/// Errors (unreadable or malformed file, a file it refers to that cannot be
/// opened, a texture that cannot be decoded) name `meshPath`. May throw only
/// what assimp or the allocator throws; LoadScene catches it.
/// Most bytes the decoded textures of one mesh file may take in all (each is
/// also bounded by kMaxImageBytes): a file embedding many small images that
/// decode large cannot take any amount of memory.
inline constexpr int64_t kMaxSceneTextureBytes = int64_t(1) << 30;

/// Part of a mesh file to import as a movable object (a scene file's
/// "group" object, issue 14): the triangles of every mesh under an assimp
/// node called one of `nodeNames` (OBJ `o`/`g` names, glTF node names), or
/// under any of its descendants.
struct MeshGroup {
  std::vector<std::string> nodeNames;
  /// The world point that becomes the object's origin: object-space
  /// positions are world positions minus it. Default: the centre of the
  /// group's world bounding box.
  std::optional<Vec3> pivot;
  /// Name and animation of the object. Its objectToWorld and animation keys
  /// are relative to the home frame translate(pivot); ImportMesh composes
  /// them with it before handing the object to SceneBuilder::BeginObject.
  MovableObject object;
};

/// With `groups`, the triangles under the named nodes become movable objects
/// (BeginObject in the order of `groups`, each group's triangles in its object
/// space); the rest stay static. The static part keeps assimp's mesh order,
/// which differs from the order without groups (meshes sharing a material are
/// then not merged). Errors name the mesh file and the object: a name no node
/// has (the message lists the nodes there are), a group without triangles, a
/// node claimed by two objects, groups that would leave nothing static.
Status ImportMesh(const std::filesystem::path& meshPath, SceneBuilder& builder,
                  std::span<const MeshGroup> groups = {});

}  // namespace penumbra
