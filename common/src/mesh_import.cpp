#include "mesh_import.h"

#include <algorithm>
#include <cerrno>
#include <csignal>
#include <cstring>
#include <chrono>
#include <thread>
#include <fstream>
#include <iterator>
#include <map>
#include <mutex>
#include <tuple>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <assimp/DefaultIOSystem.h>
#include <assimp/Importer.hpp>
#include <assimp/config.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <nlohmann/json.hpp>

#include "io_util.h"
#include "penumbra/common/image_io.h"
#include "penumbra/common/logging.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;

// Assimp silently carries on when a file the mesh refers to (an OBJ's
// mtllib) cannot be opened; remembering failed opens lets us report it.
class RecordingIOSystem : public Assimp::DefaultIOSystem {
 public:
  Assimp::IOStream* Open(const char* file, const char* mode) override {
    Assimp::IOStream* stream = DefaultIOSystem::Open(file, mode);
    if (!stream && failedOpen_.empty()) failedOpen_ = file;
    return stream;
  }
  const std::string& FirstFailedOpen() const { return failedOpen_; }

 private:
  std::string failedOpen_;
};

// 8- and 16-bit texture files hold sRGB-encoded values, float files linear ones.
Texture TextureFromImage(Image image, std::string name) {
  Texture texture;
  texture.path = std::move(name);
  texture.width = image.width;
  texture.height = image.height;
  texture.texels.resize(size_t(image.width) * size_t(image.height));
  for (size_t i = 0; i < texture.texels.size(); ++i) {
    const Rgb stored(image.rgb[3 * i], image.rgb[3 * i + 1], image.rgb[3 * i + 2]);
    texture.texels[i] = image.storedAsFloat
                            ? stored
                            : Rgb(SrgbToLinear(stored.r), SrgbToLinear(stored.g), SrgbToLinear(stored.b));
  }
  return texture;
}

// Decodes each texture once and hands out its SceneBuilder index.
class TextureCache {
 public:
  TextureCache(const aiScene& scene, const fs::path& meshPath, SceneBuilder& builder)
      : scene_(scene), meshPath_(meshPath), builder_(builder) {}

  /// `reference` is a material's texture string: a file path relative to the
  /// mesh file, or "*N" / a name for an image embedded in the mesh file.
  /// Distinct textures loaded so far.
  size_t Count() const { return indexOf_.size(); }

  Expected<int32_t> IndexOf(const std::string& reference) {
    if (const aiTexture* embedded = scene_.GetEmbeddedTexture(reference.c_str()))
      return Cached("embedded:" + reference, [&] { return DecodeEmbedded(*embedded, reference); });
    std::string portable = reference;
    std::replace(portable.begin(), portable.end(), '\\', '/');  // paths written on Windows
    const fs::path file = meshPath_.parent_path() / fs::path(portable);
    std::error_code ec;
    const fs::path canonical = fs::weakly_canonical(file, ec);
    return Cached(ec ? file.string() : canonical.string(), [&]() -> Expected<Image> {
      if (auto ok = io::CheckRegularFile(file); !ok)
        return Fail(fmt::format("texture '{}': {}", reference, ok.error().message));
      return ReadImage(file);
    });
  }

 private:
  template <class Decoder>
  Expected<int32_t> Cached(const std::string& key, Decoder decode) {
    if (auto it = indexOf_.find(key); it != indexOf_.end()) return it->second;
    Expected<Image> image = decode();
    if (!image) return image.error();
    // Each image is bounded (kMaxImageBytes); so is their sum, or a file
    // embedding many could still take any amount of memory.
    const int64_t bytes = int64_t(image->rgb.size() * sizeof(float));
    if (textureBytes_ + bytes > kMaxSceneTextureBytes)
      return Fail(fmt::format("texture '{}': the scene's textures would take over {} MiB", key,
                              kMaxSceneTextureBytes >> 20));
    textureBytes_ += bytes;
    const int32_t index = builder_.AddTexture(TextureFromImage(std::move(*image), key));
    indexOf_.emplace(key, index);
    return index;
  }

  Expected<Image> DecodeEmbedded(const aiTexture& texture, const std::string& reference) const {
    const std::string name = fmt::format("{}: embedded texture '{}'", meshPath_.string(), reference);
    if (texture.mHeight == 0) {  // compressed file bytes; mWidth is their count
      const auto* bytes = reinterpret_cast<const std::byte*>(texture.pcData);
      return ReadImageFromMemory(std::span(bytes, texture.mWidth), texture.achFormatHint, name);
    }
    // Uncompressed 8-bit BGRA texels; the size is the file's word.
    if (auto ok = CheckImageSize(texture.mWidth, texture.mHeight, name); !ok) return ok.error();
    Image image;
    image.width = int(texture.mWidth);
    image.height = int(texture.mHeight);
    image.rgb.reserve(size_t(texture.mWidth) * texture.mHeight * 3);
    for (size_t i = 0; i < size_t(texture.mWidth) * texture.mHeight; ++i) {
      const aiTexel& t = texture.pcData[i];
      image.rgb.insert(image.rgb.end(), {t.r / 255.0f, t.g / 255.0f, t.b / 255.0f});
    }
    return image;
  }

  const aiScene& scene_;
  const fs::path& meshPath_;
  SceneBuilder& builder_;
  std::unordered_map<std::string, int32_t> indexOf_;
  int64_t textureBytes_ = 0;
};

// A GLB's header and chunk headers declare sizes that assimp allocates before
// reading them (a 24-byte file declaring a 2 GB chunk cost 13.6 s and 2.1 GiB
// before its error), so they are checked against the file's size first.
// Files that do not start with the GLB magic are left to assimp.
Status CheckGlbSizes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char header[20];
  auto u32 = [&](size_t at) {
    return uint32_t(header[at]) | uint32_t(header[at + 1]) << 8 | uint32_t(header[at + 2]) << 16 |
           uint32_t(header[at + 3]) << 24;
  };
  if (!in.read(reinterpret_cast<char*>(header), 12) || std::memcmp(header, "glTF", 4) != 0) return Status::Ok();
  std::error_code ec;
  const uint64_t fileBytes = fs::file_size(path, ec);
  if (ec) return Fail(fmt::format("{}: {}", path.string(), ec.message()));
  const uint32_t version = u32(4), length = u32(8);
  if (length > fileBytes || length < 12)
    return Fail(fmt::format("{}: the GLB header declares {} bytes but the file has {}", path.string(), length,
                            fileBytes));
  if (version == 1) {  // glTF 1.0 binary: one JSON content block after a 20-byte header
    if (!in.read(reinterpret_cast<char*>(header + 12), 8) || length < 20 || u32(12) > length - 20)
      return Fail(fmt::format("{}: the GLB (version 1) content does not fit in its {} bytes", path.string(), length));
    return Status::Ok();
  }
  // Assimp reads the first (JSON) chunk's header whatever the total length
  // says, and allocates what it declares: it must be there.
  if (length < 20)
    return Fail(fmt::format("{}: the GLB header declares {} bytes, too few for its JSON chunk", path.string(),
                            length));
  uint64_t at = 12;
  for (int chunk = 0; at + 8 <= length; ++chunk) {
    in.seekg(std::streamoff(at));
    if (!in.read(reinterpret_cast<char*>(header), 8))
      return Fail(fmt::format("{}: cannot read GLB chunk {}", path.string(), chunk));
    const uint32_t chunkBytes = u32(0);
    if (chunkBytes > length - at - 8)
      return Fail(fmt::format("{}: GLB chunk {} declares {} bytes but only {} follow", path.string(), chunk,
                              chunkBytes, length - at - 8));
    at += 8 + uint64_t(chunkBytes);
  }
  return Status::Ok();
}

Rgb ToRgb(const aiColor3D& c) { return Rgb(c.r, c.g, c.b); }

struct ConvertedMaterial {
  Material material;
  unsigned uvChannel = 0;  // the UV set the albedo texture uses
};

Expected<ConvertedMaterial> ConvertMaterial(const aiMaterial& source, TextureCache& textures) {
  ConvertedMaterial out;
  Material& m = out.material;
  m.name = source.GetName().C_Str();

  // glTF's base colour wins over the diffuse colour assimp derives from it.
  aiColor3D colour;
  if (source.Get(AI_MATKEY_BASE_COLOR, colour) == aiReturn_SUCCESS ||
      source.Get(AI_MATKEY_COLOR_DIFFUSE, colour) == aiReturn_SUCCESS)
    m.albedo = ToRgb(colour);

  for (aiTextureType type : {aiTextureType_BASE_COLOR, aiTextureType_DIFFUSE}) {
    aiString reference;
    if (source.GetTexture(type, 0, &reference) != aiReturn_SUCCESS) continue;
    auto index = textures.IndexOf(reference.C_Str());
    if (!index) return Fail(fmt::format("material '{}': {}", m.name, index.error().message));
    m.albedoTexture = *index;
    source.Get(AI_MATKEY_UVWSRC(type, 0), out.uvChannel);
    break;
  }

  if (source.Get(AI_MATKEY_COLOR_EMISSIVE, colour) == aiReturn_SUCCESS) m.emission = ToRgb(colour);
  return out;
}

// Assimp 5.2 drops KHR_materials_emissive_strength, which exporters (Blender)
// write for any emission brighter than 1, so it is read from the glTF JSON
// here. Indexed like the file's materials, which assimp imports in order.
// Best effort: assimp has already read the file, and a layout this cannot
// follow leaves the strengths at 1 (an empty result).
std::vector<float> GltfEmissiveStrengths(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::string text;
  if (io::LowerExtension(path) == ".glb") {
    // 12-byte header (magic, version, length), then the JSON chunk's length
    // and type; little-endian, like every host this builds for.
    uint32_t header[5];
    if (!in.read(reinterpret_cast<char*>(header), sizeof header) || header[4] != 0x4E4F534Au /* "JSON" */ ||
        header[3] > header[2])
      return {};
    text.resize(header[3]);
    if (!in.read(text.data(), std::streamsize(text.size()))) return {};
  } else {
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  try {
    const auto doc = nlohmann::json::parse(text);
    const nlohmann::json::json_pointer strengthKey("/extensions/KHR_materials_emissive_strength/emissiveStrength");
    std::vector<float> strengths;
    for (const auto& material : doc.at("materials")) {
      const bool given = material.contains(strengthKey) && material.at(strengthKey).is_number();
      strengths.push_back(given ? material.at(strengthKey).get<float>() : 1.0f);
    }
    return strengths;
  } catch (const nlohmann::json::exception&) {
    return {};
  }
}

Vec3 ToVec3(const aiVector3D& v) { return Vec3(v.x, v.y, v.z); }

constexpr unsigned kImportFlags = aiProcess_Triangulate | aiProcess_PreTransformVertices;

// Assimp 5.2.4 (Debian 12) crashes on some malformed files: the fuzz targets
// found a SEGV in its OBJ reader and one in its glTF 2 reader (a mimeType
// without "image/"). So that such a file is an error and never takes a
// process down, assimp first reads it in a forked child; only when the child
// survives does this process read it (assimp is deterministic). This costs
// a second parse of the mesh file at start-up. The child only parses and
// exits (no threads, no logging, no exit handlers).
Status ReadsWithoutCrashing(const fs::path& meshPath, bool keepHierarchy) {
  const pid_t child = fork();
  if (child < 0) return Status::Ok();  // cannot probe: read it here, as without the probe
  if (child == 0) {
    Assimp::Importer importer;
    importer.SetPropertyBool(AI_CONFIG_PP_PTV_KEEP_HIERARCHY, keepHierarchy);
    importer.ReadFile(meshPath.string(), kImportFlags);
    _exit(0);
  }
  // The probe is a safety net, never a new way to hang: a child that has not
  // finished within 5 s plus 1 s per 10 MB of file (assimp reads Sponza's
  // 20 MB in well under 2 s) is killed, and this process reads the file
  // without the net. (Seen once in a fuzz run, under ASan: a forked child
  // stuck on its first, empty input -- a lock another thread held at fork.)
  std::error_code sizeError;
  const auto bytes = fs::file_size(meshPath, sizeError);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5) +
                        std::chrono::seconds(sizeError ? 0 : bytes / 10'000'000);
  int status = 0;
  for (;;) {
    const pid_t done = waitpid(child, &status, WNOHANG);
    if (done == child) break;
    if (done < 0 && errno != EINTR) return Status::Ok();
    if (std::chrono::steady_clock::now() >= deadline) {
      kill(child, SIGKILL);
      while (waitpid(child, &status, 0) < 0 && errno == EINTR) {
      }
      Logger("scene")->warn("{}: the crash probe of the mesh reader did not finish in time; reading without it",
                            meshPath.string());
      return Status::Ok();
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  if (WIFSIGNALED(status))
    return Fail(fmt::format("{}: the mesh reader (assimp) crashed on this file (signal {}, {}); the file is malformed",
                            meshPath.string(), WTERMSIG(status), strsignal(WTERMSIG(status))));
  if (WIFEXITED(status) && WEXITSTATUS(status) != 0)  // a sanitizer's report ends the child so
    return Fail(fmt::format("{}: the mesh reader (assimp) crashed on this file (exit status {}); the file is malformed",
                            meshPath.string(), WEXITSTATUS(status)));
  return Status::Ok();
}

// The probe's verdict, remembered per file for the life of the process: a
// scene that places one mesh file many times (movable objects, instances)
// forks once for it, not once per use. Forking is cheap in a release build
// but not under AddressSanitizer (its shadow mappings make each fork of a
// large process take a second or more: 64 objects of one mesh took 2.5 min
// in the scene-file fuzzer, whose inputs then timed out). A file is known by
// device, inode, size and modification time, so a file changed or replaced
// since is probed again. (Only the mesh file is in the key, not the .mtl
// files it names; a crashing .mtl swapped in under an unchanged OBJ within
// one process's life is not caught.)
Status ProbedReadsWithoutCrashing(const fs::path& meshPath, bool keepHierarchy) {
  struct stat info {};
  if (stat(meshPath.c_str(), &info) != 0) return ReadsWithoutCrashing(meshPath, keepHierarchy);
  using Key = std::tuple<dev_t, ino_t, off_t, int64_t, int64_t, bool>;
  const Key key{info.st_dev, info.st_ino, info.st_size, int64_t(info.st_mtim.tv_sec), int64_t(info.st_mtim.tv_nsec),
                keepHierarchy};
  static std::mutex mutex;
  static std::map<Key, Status> verdicts;
  {
    std::lock_guard lock(mutex);
    if (auto it = verdicts.find(key); it != verdicts.end()) return it->second;
  }
  Status verdict = ReadsWithoutCrashing(meshPath, keepHierarchy);
  std::lock_guard lock(mutex);
  // At most a few hundred distinct files are ever read by one process; keep
  // the map bounded anyway (a long-lived process reloading changed files).
  if (verdicts.size() >= 4096) verdicts.clear();
  verdicts.emplace(key, verdict);
  return verdict;
}

constexpr size_t kNoGroup = ~size_t(0);

// The group (index into `groups`) each of the file's meshes belongs to, or
// kNoGroup for the static part: a mesh belongs to the group naming the
// nearest node above it (or its own node).
Expected<std::vector<size_t>> AssignMeshesToGroups(const aiScene& scene, std::span<const MeshGroup> groups,
                                                   const std::string& where) {
  auto objectName = [&](size_t g) { return groups[g].object.name; };
  std::unordered_map<std::string, size_t> groupOfName;
  for (size_t g = 0; g < groups.size(); ++g) {
    for (const std::string& name : groups[g].nodeNames) {
      const auto [it, inserted] = groupOfName.emplace(name, g);
      if (!inserted && it->second != g)
        return Fail(fmt::format("{}: objects.{} and objects.{} both name the group \"{}\"", where,
                                objectName(it->second), objectName(g), name));
    }
  }
  std::vector<size_t> groupOfMesh(scene.mNumMeshes, kNoGroup);
  std::vector<bool> meshPlaced(scene.mNumMeshes, false);
  std::unordered_set<std::string> found;
  std::vector<std::string> nodeNames;  // distinct, in tree order: for the message of a name not found
  std::unordered_set<std::string> listed;
  // An explicit stack: the file decides how deep its tree is.
  struct Pending {
    const aiNode* node;
    size_t group;  // of the nearest node above that a group names
  };
  std::vector<Pending> stack;
  if (scene.mRootNode) stack.push_back({scene.mRootNode, kNoGroup});
  while (!stack.empty()) {
    const Pending item = stack.back();
    stack.pop_back();
    const aiNode& node = *item.node;
    const std::string name = node.mName.C_Str();
    if (listed.insert(name).second) nodeNames.push_back(name);
    size_t group = item.group;
    if (const auto it = groupOfName.find(name); it != groupOfName.end()) {
      found.insert(name);
      if (group != kNoGroup && group != it->second)
        return Fail(fmt::format("{}: objects.{}: node \"{}\" is inside a node of objects.{}", where,
                                objectName(it->second), name, objectName(group)));
      group = it->second;
    }
    for (unsigned i = 0; i < node.mNumMeshes; ++i) {
      const unsigned mesh = node.mMeshes[i];
      if (mesh >= scene.mNumMeshes)
        return Fail(fmt::format("{}: node \"{}\" refers to mesh {} of {}", where, name, mesh, scene.mNumMeshes));
      if (meshPlaced[mesh] && groupOfMesh[mesh] != group)
        return Fail(fmt::format("{}: mesh '{}' is used under the nodes of two parts (a movable object and the static "
                                "part, or two objects)",
                                where,
                                scene.mMeshes[mesh]->mName.C_Str()));
      meshPlaced[mesh] = true;
      groupOfMesh[mesh] = group;
    }
    for (unsigned i = node.mNumChildren; i-- > 0;)  // reversed: children are visited in file order
      if (node.mChildren[i]) stack.push_back({node.mChildren[i], group});
  }
  for (size_t g = 0; g < groups.size(); ++g) {
    for (const std::string& name : groups[g].nodeNames) {
      if (found.count(name)) continue;
      constexpr size_t kListed = 128;
      const size_t shown = std::min(nodeNames.size(), kListed);
      return Fail(fmt::format("{}: objects.{}: no node (OBJ o/g group, glTF node) is called \"{}\"; the file has: "
                              "\"{}\"{}",
                              where, objectName(g), name,
                              fmt::join(nodeNames.begin(), nodeNames.begin() + std::ptrdiff_t(shown), "\", \""),
                              nodeNames.size() > shown ? fmt::format(" and {} more", nodeNames.size() - shown) : ""));
    }
  }
  return groupOfMesh;
}

// `placement` (relative to the home frame) composed with `home`, checked as
// the wire checks transforms: a pivot far out can take it beyond range.
Expected<RigidTransform> PlaceAtHome(const RigidTransform& home, const RigidTransform& placement) {
  const auto m = home.Compose(placement).ToRowMajor();
  return RigidTransform::FromRowMajor(m);
}
}  // namespace

Status ImportMesh(const fs::path& meshPath, SceneBuilder& builder, std::span<const MeshGroup> groups) {
  const std::string where = meshPath.string();
  if (auto ok = io::CheckRegularFile(meshPath); !ok) return ok;
  if (auto ok = CheckGlbSizes(meshPath); !ok) return ok;
  // Phases with counts and times: a big scene takes a while, and the log is
  // all there is to watch meanwhile.
  auto log = Logger("scene");
  using Clock = std::chrono::steady_clock;
  auto since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  std::error_code sizeError;
  const auto fileBytes = fs::file_size(meshPath, sizeError);
  log->info("reading {} ({:.1f} MB)", where, sizeError ? 0.0 : double(fileBytes) / 1e6);
  const auto readStart = Clock::now();
  // Groups need the file's nodes, which pre-transforming otherwise merges
  // away (meshes sharing a material become one).
  const bool keepHierarchy = !groups.empty();
  if (auto ok = ProbedReadsWithoutCrashing(meshPath, keepHierarchy); !ok) return ok;

  Assimp::Importer importer;
  importer.SetPropertyBool(AI_CONFIG_PP_PTV_KEEP_HIERARCHY, keepHierarchy);
  auto* io = new RecordingIOSystem;  // the importer owns it
  importer.SetIOHandler(io);
  // No vertex joining or normal generation: SceneBuilder welds by position and
  // splits at creases itself, identically for every format.
  const aiScene* scene = importer.ReadFile(where, kImportFlags);
  if (!scene) return Fail(fmt::format("{}: {}", where, io::OneLine(importer.GetErrorString())));
  if (!io->FirstFailedOpen().empty())
    return Fail(fmt::format("{}: cannot open '{}', which it refers to", where, io->FirstFailedOpen()));
  if (scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE)
    return Fail(fmt::format("{}: the file is incomplete (assimp could not read all of it)", where));
  size_t faces = 0;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) faces += scene->mMeshes[m]->mNumFaces;
  log->info("read {} meshes, {} faces, {} materials in {:.2f} s; converting materials and loading textures",
            scene->mNumMeshes, faces, scene->mNumMaterials, since(readStart));
  const auto convertStart = Clock::now();

  struct UsedMaterial {
    uint32_t builderIndex;
    unsigned uvChannel;
  };
  const std::string ext = io::LowerExtension(meshPath);
  const std::vector<float> emissiveStrengths =
      ext == ".gltf" || ext == ".glb" ? GltfEmissiveStrengths(meshPath) : std::vector<float>{};
  TextureCache textures(*scene, meshPath, builder);
  std::vector<std::optional<UsedMaterial>> used(scene->mNumMaterials);
  // Adds one mesh's triangles, each corner minus `origin` (the object-space
  // origin of a group; zero for the static part).
  auto addMesh = [&](unsigned meshIndex, const Vec3& origin) -> Status {
    const aiMesh& mesh = *scene->mMeshes[meshIndex];
    if (mesh.mMaterialIndex >= scene->mNumMaterials)
      return Fail(fmt::format("{}: mesh '{}' refers to material {} of {}", where, mesh.mName.C_Str(),
                              mesh.mMaterialIndex, scene->mNumMaterials));
    // Materials are converted when first used, so unused ones (assimp's
    // DefaultMaterial for OBJ files) neither load textures nor count.
    auto& material = used[mesh.mMaterialIndex];
    if (!material) {
      auto result = ConvertMaterial(*scene->mMaterials[mesh.mMaterialIndex], textures);
      if (!result) return Fail(fmt::format("{}: {}", where, result.error().message));
      if (mesh.mMaterialIndex < emissiveStrengths.size())
        result->material.emission *= emissiveStrengths[mesh.mMaterialIndex];
      material = UsedMaterial{builder.AddMaterial(std::move(result->material)), result->uvChannel};
    }
    const aiVector3D* uvs =
        mesh.HasTextureCoords(material->uvChannel) ? mesh.mTextureCoords[material->uvChannel] : nullptr;
    for (unsigned f = 0; f < mesh.mNumFaces; ++f) {
      const aiFace& face = mesh.mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines carry no surface
      std::array<Vec3, 3> positions;
      std::array<Vec2, 3> uv{};
      for (int c = 0; c < 3; ++c) {
        const unsigned v = face.mIndices[c];
        if (v >= mesh.mNumVertices)
          return Fail(fmt::format("{}: mesh '{}' face {} refers to vertex {} of {}", where, mesh.mName.C_Str(), f,
                                  v, mesh.mNumVertices));
        positions[c] = ToVec3(mesh.mVertices[v]) - origin;
        if (uvs) uv[c] = Vec2(uvs[v].x, uvs[v].y);
      }
      builder.AddTriangle(positions, material->builderIndex, uv);
    }
    return Status::Ok();
  };

  if (groups.empty()) {
    for (unsigned meshIndex = 0; meshIndex < scene->mNumMeshes; ++meshIndex)
      if (auto ok = addMesh(meshIndex, Vec3(0.0f)); !ok) return ok;
  } else {
    auto groupOfMesh = AssignMeshesToGroups(*scene, groups, where);
    if (!groupOfMesh) return groupOfMesh.error();
    // Each group's world bounds (for its default pivot) and triangle count.
    std::vector<Bounds3> bounds(groups.size());
    std::vector<size_t> triangles(groups.size(), 0);
    size_t staticTriangles = 0;
    for (unsigned meshIndex = 0; meshIndex < scene->mNumMeshes; ++meshIndex) {
      const aiMesh& mesh = *scene->mMeshes[meshIndex];
      const size_t group = (*groupOfMesh)[meshIndex];
      for (unsigned f = 0; f < mesh.mNumFaces; ++f) {
        const aiFace& face = mesh.mFaces[f];
        if (face.mNumIndices != 3) continue;
        if (group == kNoGroup) {
          ++staticTriangles;
          continue;
        }
        ++triangles[group];
        for (int c = 0; c < 3; ++c)
          if (face.mIndices[c] < mesh.mNumVertices) bounds[group].Extend(ToVec3(mesh.mVertices[face.mIndices[c]]));
      }
    }
    for (size_t g = 0; g < groups.size(); ++g)
      if (triangles[g] == 0)
        return Fail(fmt::format("{}: objects.{}: the group \"{}\" has no triangles", where, groups[g].object.name,
                                fmt::join(groups[g].nodeNames, "\", \"")));
    if (staticTriangles == 0)
      return Fail(fmt::format("{}: the movable objects' groups take every triangle; nothing would stay static "
                              "(to move a whole file, give it as an object's \"mesh\")",
                              where));
    for (unsigned meshIndex = 0; meshIndex < scene->mNumMeshes; ++meshIndex)
      if ((*groupOfMesh)[meshIndex] == kNoGroup)
        if (auto ok = addMesh(meshIndex, Vec3(0.0f)); !ok) return ok;
    for (size_t g = 0; g < groups.size(); ++g) {
      const Vec3 pivot = groups[g].pivot.value_or(bounds[g].Center());
      RigidTransform home;  // world axes, origin at the pivot
      home.translation = pivot;
      MovableObject object = groups[g].object;
      auto placed = PlaceAtHome(home, object.objectToWorld);
      if (!placed) return Fail(fmt::format("{}: objects.{}: {}", where, object.name, placed.error().message));
      object.objectToWorld = *placed;
      if (object.animation) {
        for (ObjectKeyframe& key : object.animation->keys) {
          auto keyPlaced = PlaceAtHome(home, key.objectToWorld);
          if (!keyPlaced)
            return Fail(fmt::format("{}: objects.{}: the keyframe at t = {}: {}", where, object.name, key.timeS,
                                    keyPlaced.error().message));
          key.objectToWorld = *keyPlaced;
        }
      }
      builder.BeginObject(std::move(object));
      for (unsigned meshIndex = 0; meshIndex < scene->mNumMeshes; ++meshIndex)
        if ((*groupOfMesh)[meshIndex] == g)
          if (auto ok = addMesh(meshIndex, pivot); !ok) {
            builder.EndObject();
            return ok;
          }
      builder.EndObject();
    }
  }
  log->info("converted {} meshes: {} textures loaded in {:.2f} s", scene->mNumMeshes, textures.Count(),
            since(convertStart));
  return Status::Ok();
}

}  // namespace penumbra
