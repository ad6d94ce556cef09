#pragma once
// Mesh files (OBJ/MTL, glTF, GLB and whatever else assimp reads) into a
// SceneBuilder. Private to penumbra_scene_io; LoadScene is the public entry.

#include <filesystem>

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

Status ImportMesh(const std::filesystem::path& meshPath, SceneBuilder& builder);

}  // namespace penumbra
