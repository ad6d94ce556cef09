// Scene data, SceneBuilder (welding and crease splitting) and Finalize().
// File loading lives in scene_loader.cpp.

#include "penumbra/common/scene.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <unordered_map>
#include <unordered_set>

#include <fmt/format.h>

#include "penumbra/common/hash.h"

namespace penumbra {

// --- Texture ----------------------------------------------------------------

Rgb Texture::Sample(Vec2 uv) const {
  if (width <= 0 || height <= 0 || texels.empty()) return Rgb(1.0f);
  // Continuous texel coordinates; texel centres at integer + 0.5. Image row 0
  // is the top, and v grows upward, hence the flip.
  const float x = uv.x * float(width) - 0.5f;
  const float y = (1.0f - uv.y) * float(height) - 0.5f;
  const float fx = std::floor(x);
  const float fy = std::floor(y);
  const float tx = x - fx;
  const float ty = y - fy;
  auto wrap = [](long i, int n) {
    const long m = i % n;
    return int(m < 0 ? m + n : m);
  };
  // Coordinates far outside [0,1] (tiling UVs) stay exact through the wrap.
  const long ix = std::isfinite(fx) ? long(fx) : 0;
  const long iy = std::isfinite(fy) ? long(fy) : 0;
  const int x0 = wrap(ix, width), x1 = wrap(ix + 1, width);
  const int y0 = wrap(iy, height), y1 = wrap(iy + 1, height);
  auto at = [&](int xx, int yy) -> const Rgb& { return texels[size_t(yy) * size_t(width) + size_t(xx)]; };
  const Rgb top = (1.0f - tx) * at(x0, y0) + tx * at(x1, y0);
  const Rgb bottom = (1.0f - tx) * at(x0, y1) + tx * at(x1, y1);
  return (1.0f - ty) * top + ty * bottom;
}

// --- SkyLight ---------------------------------------------------------------

Rgb SkyLight::Radiance(const Vec3& direction) const {
  const float c = std::clamp(glm::dot(direction, up), -1.0f, 1.0f);
  return c >= 0.0f ? glm::mix(horizon, zenith, c) : glm::mix(horizon, ground, -c);
}

// --- Scene ------------------------------------------------------------------

Vec3 Scene::GeometricNormal(uint32_t triangle) const {
  const Vec3& p0 = Position(triangle, 0);
  const Vec3 n = glm::cross(Position(triangle, 1) - p0, Position(triangle, 2) - p0);
  const float len = glm::length(n);
  return len > 0.0f ? n / len : Vec3(0.0f, 0.0f, 1.0f);
}

float Scene::Area(uint32_t triangle) const {
  const Vec3& p0 = Position(triangle, 0);
  return 0.5f * glm::length(glm::cross(Position(triangle, 1) - p0, Position(triangle, 2) - p0));
}

Vec3 Scene::PointAt(uint32_t triangle, float b1, float b2) const {
  return (1.0f - b1 - b2) * Position(triangle, 0) + b1 * Position(triangle, 1) +
         b2 * Position(triangle, 2);
}

Rgb Scene::AlbedoAt(uint32_t triangle, float b1, float b2) const {
  const Triangle& tri = triangles[triangle];
  const Material& m = materials[tri.material];
  if (m.albedoTexture < 0) return m.albedo;
  const Vec2 uv = (1.0f - b1 - b2) * tri.uv[0] + b1 * tri.uv[1] + b2 * tri.uv[2];
  return m.albedo * textures[size_t(m.albedoTexture)].Sample(uv);
}

uint32_t Scene::ObjectOfTriangle(uint32_t triangle) const {
  if (triangle < staticTriangleCount || objects.empty()) return kStaticObject;
  // Ranges are contiguous and increasing (Finalize checks it): the last
  // object starting at or before `triangle`.
  const auto it = std::upper_bound(objects.begin(), objects.end(), triangle,
                                   [](uint32_t t, const MovableObject& o) { return t < o.firstTriangle; });
  return uint32_t(it - objects.begin()) - 1;
}

uint32_t Scene::ObjectOfVertex(uint32_t vertex) const {
  if (vertex < staticVertexCount || objects.empty()) return kStaticObject;
  const auto it = std::upper_bound(objects.begin(), objects.end(), vertex,
                                   [](uint32_t v, const MovableObject& o) { return v < o.firstVertex; });
  return uint32_t(it - objects.begin()) - 1;
}

uint32_t Scene::FindObject(std::string_view objectName) const {
  for (size_t i = 0; i < objects.size(); ++i)
    if (objects[i].name == objectName) return uint32_t(i);
  return kStaticObject;
}

RigidTransform ObjectAnimation::At(double timeS) const {
  if (keys.empty()) return RigidTransform::Identity();
  if (keys.size() == 1 || !(timeS > 0.0)) return keys.front().objectToWorld;
  const double duration = DurationS();
  double t = timeS;
  if (t >= duration) {
    if (!loop || duration <= 0.0) return keys.back().objectToWorld;
    t = std::fmod(t, duration);
  }
  const auto next = std::upper_bound(keys.begin(), keys.end(), t,
                                     [](double time, const ObjectKeyframe& k) { return time < double(k.timeS); });
  if (next == keys.begin()) return keys.front().objectToWorld;
  if (next == keys.end()) return keys.back().objectToWorld;
  const ObjectKeyframe& a = *(next - 1);
  const ObjectKeyframe& b = *next;
  const double span = double(b.timeS) - double(a.timeS);
  const float s = span > 0.0 ? float((t - double(a.timeS)) / span) : 1.0f;
  return Interpolate(a.objectToWorld, b.objectToWorld, std::clamp(s, 0.0f, 1.0f));
}

ScenePose ScenePose::Initial(const Scene& scene) {
  ScenePose pose;
  pose.objectToWorld.reserve(scene.objects.size());
  for (const MovableObject& o : scene.objects) pose.objectToWorld.push_back(o.objectToWorld);
  return pose;
}

Vec3 WorldPointAt(const Scene& scene, const ScenePose& pose, uint32_t triangle, float b1, float b2) {
  const Vec3 p = scene.PointAt(triangle, b1, b2);
  const uint32_t object = scene.ObjectOfTriangle(triangle);
  return object == kStaticObject ? p : pose.objectToWorld[object].ApplyPoint(p);
}

Vec3 WorldGeometricNormal(const Scene& scene, const ScenePose& pose, uint32_t triangle) {
  const Vec3 n = scene.GeometricNormal(triangle);
  const uint32_t object = scene.ObjectOfTriangle(triangle);
  return object == kStaticObject ? n : pose.objectToWorld[object].ApplyVector(n);
}

Bounds3 WorldBounds(const Scene& scene, const ScenePose& pose, uint32_t object) {
  return pose.objectToWorld[object].ApplyBounds(scene.objects[object].objectBounds);
}

const CameraPreset* Scene::FindCamera(std::string_view cameraName) const {
  for (const auto& c : cameras)
    if (c.name == cameraName) return &c;
  return nullptr;
}

const CameraPath* Scene::FindPath(std::string_view pathName) const {
  for (const auto& p : paths)
    if (p.name == pathName) return &p;
  return nullptr;
}

namespace {

bool IsFiniteRgb(const Rgb& c) { return IsFinite(c); }

template <class T>
void HashPod(Hasher& h, const std::vector<T>& values) {
  h.Update(uint64_t(values.size()));
  h.Update(values.data(), values.size() * sizeof(T));
}

uint64_t ComputeIdentity(const Scene& s) {
  Hasher h;
  HashPod(h, s.vertices);
  h.Update(uint64_t(s.triangles.size()));
  for (const Triangle& t : s.triangles) {
    h.Update(t.v.data(), sizeof t.v);
    h.Update(t.uv.data(), sizeof t.uv);
    h.Update(uint64_t(t.material));
  }
  h.Update(uint64_t(s.materials.size()));
  for (const Material& m : s.materials) {
    h.Update(&m.albedo, sizeof m.albedo);
    h.Update(uint64_t(int64_t(m.albedoTexture)));
    h.Update(&m.emission, sizeof m.emission);
  }
  h.Update(uint64_t(s.textures.size()));
  for (const Texture& t : s.textures) {
    h.Update(uint64_t(t.width));
    h.Update(uint64_t(t.height));
    HashPod(h, t.texels);
  }
  h.Update(uint64_t(s.twoSided));
  h.Update(uint64_t(s.sun.has_value()));
  if (s.sun) {
    h.Update(&s.sun->directionToSun, sizeof(Vec3));
    h.Update(&s.sun->radiance, sizeof(Rgb));
    h.Update(&s.sun->angularDiameterRad, sizeof(float));
  }
  h.Update(uint64_t(s.sky.has_value()));
  if (s.sky) {
    h.Update(&s.sky->up, sizeof(Vec3));
    h.Update(&s.sky->zenith, sizeof(Rgb));
    h.Update(&s.sky->horizon, sizeof(Rgb));
    h.Update(&s.sky->ground, sizeof(Rgb));
  }
  h.Update(uint64_t(s.objects.size()));
  for (const MovableObject& o : s.objects) {
    h.Update(o.name.data(), o.name.size());
    h.Update(uint64_t(o.firstTriangle));
    h.Update(uint64_t(o.triangleCount));
    const auto m = o.objectToWorld.ToRowMajor();
    h.Update(m.data(), sizeof m);
    // Only for an animated object (a scene without animations keeps its
    // identity): two paths that start at the same place are different
    // scenes -- the SMA plays them, and a cache snapshot holds samples shaded
    // at their poses.
    if (o.animation) {
      h.Update(uint64_t(o.animation->loop ? 2 : 1));
      h.Update(uint64_t(o.animation->keys.size()));
      for (const ObjectKeyframe& k : o.animation->keys) {
        h.Update(&k.timeS, sizeof k.timeS);
        const auto key = k.objectToWorld.ToRowMajor();
        h.Update(key.data(), sizeof key);
      }
    }
  }
  // Only when there are instances: a scene without them keeps the identity
  // it had before they existed (saved cache snapshots stay valid).
  if (!s.instances.empty()) h.Update(uint64_t(s.instances.size()));
  for (const StaticInstance& i : s.instances) {
    for (uint32_t x : {i.firstTriangle, i.triangleCount, i.firstVertex, i.vertexCount, i.prototype})
      h.Update(uint64_t(x));
    const auto m = i.meshToWorld.ToRowMajor();
    h.Update(m.data(), sizeof m);
  }
  return h.Digest();
}

}  // namespace

float Scene::MaxEmittedRadiance() const {
  const auto maxChannel = [](const Rgb& c) { return std::max({c.r, c.g, c.b}); };
  float brightest = 0.0f;
  for (const Material& m : materials) brightest = std::max(brightest, maxChannel(m.emission));
  if (sun) brightest = std::max(brightest, maxChannel(sun->radiance));
  if (sky)
    brightest = std::max({brightest, maxChannel(sky->zenith), maxChannel(sky->horizon), maxChannel(sky->ground)});
  return brightest;
}

namespace {

Status CheckAnimation(const std::string& where, const MovableObject& o) {
  const ObjectAnimation& a = *o.animation;
  if (a.keys.size() < 2) return Fail(fmt::format("{}: object '{}': an animation needs at least 2 keyframes", where, o.name));
  if (a.keys.front().timeS != 0.0f)
    return Fail(fmt::format("{}: object '{}': the first keyframe must be at t = 0", where, o.name));
  for (size_t k = 1; k < a.keys.size(); ++k)
    if (!(a.keys[k].timeS > a.keys[k - 1].timeS) || !std::isfinite(a.keys[k].timeS))
      return Fail(fmt::format("{}: object '{}': keyframe {} at t = {} is not after the one before", where, o.name, k,
                              a.keys[k].timeS));
  return Status::Ok();
}

}  // namespace

Status Scene::CheckObjects(const std::string& where) {
  if (objects.empty()) {
    staticTriangleCount = uint32_t(triangles.size());
    staticVertexCount = uint32_t(vertices.size());
    return Status::Ok();
  }
  staticTriangleCount = objects.front().firstTriangle;
  staticVertexCount = objects.front().firstVertex;
  uint32_t nextTriangle = staticTriangleCount, nextVertex = staticVertexCount;
  for (size_t i = 0; i < objects.size(); ++i) {
    const MovableObject& o = objects[i];
    if (o.name.empty()) return Fail(fmt::format("{}: movable object {} has no name", where, i));
    for (size_t j = 0; j < i; ++j)
      if (objects[j].name == o.name) return Fail(fmt::format("{}: two movable objects are called '{}'", where, o.name));
    if (o.firstTriangle != nextTriangle || o.triangleCount == 0 || o.firstVertex != nextVertex || o.vertexCount == 0)
      return Fail(fmt::format("{}: movable object '{}' has no triangles, or its ranges do not follow the part before it",
                              where, o.name));
    nextTriangle = o.firstTriangle + o.triangleCount;
    nextVertex = o.firstVertex + o.vertexCount;
    if (o.animation)
      if (auto ok = CheckAnimation(where, o); !ok) return ok;
  }
  if (nextTriangle != triangles.size() || nextVertex != vertices.size())
    return Fail(fmt::format("{}: the movable objects' ranges do not end at the end of the scene's arrays", where));
  // Each part's triangles use only its own vertices.
  for (uint32_t t = 0; t < triangles.size(); ++t) {
    const uint32_t object = ObjectOfTriangle(t);
    for (uint32_t v : triangles[t].v)
      if (ObjectOfVertex(v) != object)
        return Fail(fmt::format("{}: triangle {} uses vertex {} of another part of the scene", where, t, v));
  }
  return Status::Ok();
}

Status Scene::CheckInstances(const std::string& where) {
  if (instances.empty()) return Status::Ok();
  uint32_t nextTriangle = instances.front().firstTriangle, nextVertex = instances.front().firstVertex;
  for (uint32_t k = 0; k < instances.size(); ++k) {
    const StaticInstance& i = instances[k];
    if (i.firstTriangle != nextTriangle || i.firstVertex != nextVertex || i.triangleCount == 0 || i.vertexCount == 0 ||
        uint64_t(i.firstTriangle) + i.triangleCount > staticTriangleCount ||
        uint64_t(i.firstVertex) + i.vertexCount > staticVertexCount)
      return Fail(fmt::format("{}: instance {} has no triangles, or its ranges do not follow the part before it "
                              "within the static part", where, k));
    nextTriangle = i.firstTriangle + i.triangleCount;
    nextVertex = i.firstVertex + i.vertexCount;
    if (i.prototype > k || instances[i.prototype].prototype != i.prototype)
      return Fail(fmt::format("{}: instance {} names instance {} as its prototype, which is not a first copy", where,
                              k, i.prototype));
    const StaticInstance& p = instances[i.prototype];
    if (p.triangleCount != i.triangleCount || p.vertexCount != i.vertexCount)
      return Fail(fmt::format("{}: instance {} has {} triangles and {} vertices, its prototype {} and {}", where, k,
                              i.triangleCount, i.vertexCount, p.triangleCount, p.vertexCount));
    // The ray tracers share the prototype's acceleration structure among the
    // copies and name a hit by (copy, triangle of the prototype): the same
    // triangles must use the same vertices.
    for (uint32_t j = 0; j < i.triangleCount; ++j)
      for (int c = 0; c < 3; ++c) {
        const uint32_t v = triangles[i.firstTriangle + j].v[c];
        if (v < i.firstVertex || v - i.firstVertex >= i.vertexCount ||
            v - i.firstVertex != triangles[p.firstTriangle + j].v[c] - p.firstVertex)
          return Fail(fmt::format("{}: triangle {} of instance {} does not match its prototype's", where, j, k));
      }
  }
  if (nextTriangle != staticTriangleCount || nextVertex != staticVertexCount)
    return Fail(fmt::format("{}: the instances' ranges do not end where the static part does", where));
  return Status::Ok();
}

Status Scene::Finalize() {
  const std::string where = sourcePath.empty() ? name : sourcePath.string();
  if (triangles.empty()) return Fail(fmt::format("{}: the scene has no triangles", where));
  if (materials.empty()) return Fail(fmt::format("{}: the scene has no materials", where));
  // Positions first: a non-finite coordinate also spoils its neighbours'
  // normals, and the coordinate is the problem to report.
  for (size_t i = 0; i < vertices.size(); ++i)
    if (!IsFinite(vertices[i].position))
      return Fail(fmt::format("{}: vertex {} has a non-finite coordinate", where, i));
  for (size_t i = 0; i < vertices.size(); ++i)
    if (!IsFinite(vertices[i].normal))
      return Fail(fmt::format("{}: vertex {} has a non-finite normal", where, i));
  for (size_t i = 0; i < triangles.size(); ++i) {
    for (uint32_t v : triangles[i].v)
      if (v >= vertices.size())
        return Fail(fmt::format("{}: triangle {} refers to vertex {} of {}", where, i, v, vertices.size()));
    if (triangles[i].material >= materials.size())
      return Fail(fmt::format("{}: triangle {} refers to material {} of {}", where, i,
                              triangles[i].material, materials.size()));
  }
  for (const Material& m : materials) {
    if (!IsFiniteRgb(m.albedo) || !IsFiniteRgb(m.emission))
      return Fail(fmt::format("{}: material '{}' has a non-finite colour", where, m.name));
    if (m.albedoTexture >= int32_t(textures.size()))
      return Fail(fmt::format("{}: material '{}' refers to texture {} of {}", where, m.name,
                              m.albedoTexture, textures.size()));
  }
  if (textures.size() > kMaxSceneTextures)
    return Fail(fmt::format("{}: {} textures; at most {} are supported", where, textures.size(), kMaxSceneTextures));
  for (const Texture& t : textures)
    if (t.width <= 0 || t.height <= 0 || t.texels.size() != size_t(t.width) * size_t(t.height))
      return Fail(fmt::format("{}: texture '{}' has inconsistent size", where, t.path));
  if (sun && (!IsFinite(sun->directionToSun) || !IsFiniteRgb(sun->radiance) ||
              !(sun->angularDiameterRad > 0.0f && sun->angularDiameterRad < kPi)))
    return Fail(fmt::format("{}: the sun needs a finite direction and radiance and an angular diameter in (0, 180) degrees", where));
  if (sun) sun->directionToSun = glm::normalize(sun->directionToSun);
  if (sky && (!IsFinite(sky->up) || glm::length(sky->up) == 0.0f || !IsFiniteRgb(sky->zenith) ||
              !IsFiniteRgb(sky->horizon) || !IsFiniteRgb(sky->ground)))
    return Fail(fmt::format("{}: the sky needs a finite up direction and finite radiances", where));
  if (sky) sky->up = glm::normalize(sky->up);

  if (auto ok = CheckObjects(where); !ok) return ok;
  if (auto ok = CheckInstances(where); !ok) return ok;

  emissiveTriangles.clear();
  bounds = Bounds3{};
  for (uint32_t i = 0; i < triangles.size(); ++i) {
    if (MaterialOf(i).IsEmissive()) {
      if (i >= staticTriangleCount)
        return Fail(fmt::format("{}: movable object '{}' has an emissive material ('{}'); moving lights are not "
                                "supported",
                                where, objects[ObjectOfTriangle(i)].name, MaterialOf(i).name));
      emissiveTriangles.push_back(i);
    }
  }
  for (uint32_t i = 0; i < staticTriangleCount; ++i)
    for (int c = 0; c < 3; ++c) bounds.Extend(Position(i, c));
  for (MovableObject& o : objects) {
    o.objectBounds = Bounds3{};
    for (uint32_t v = o.firstVertex; v < o.firstVertex + o.vertexCount; ++v) o.objectBounds.Extend(vertices[v].position);
    const Bounds3 world = o.objectToWorld.ApplyBounds(o.objectBounds);
    bounds.Extend(world.min);
    bounds.Extend(world.max);
  }
  identity = ComputeIdentity(*this);
  return Status::Ok();
}

// --- SceneBuilder -----------------------------------------------------------

SceneBuilder::SceneBuilder(float creaseAngleDeg)
    : cosCrease_(std::cos(std::clamp(creaseAngleDeg, 0.0f, 180.0f) * kPi / 180.0f)) {}

uint32_t SceneBuilder::BeginObject(MovableObject object) {
  objects_.push_back(std::move(object));
  currentObject_ = uint32_t(objects_.size() - 1);
  return currentObject_;
}

uint32_t SceneBuilder::AddMaterial(Material material) {
  materials_.push_back(std::move(material));
  return uint32_t(materials_.size() - 1);
}

int32_t SceneBuilder::AddTexture(Texture texture) {
  textures_.push_back(std::move(texture));
  return int32_t(textures_.size() - 1);
}

void SceneBuilder::AddTriangle(const std::array<Vec3, 3>& positions, uint32_t material,
                               const std::array<Vec2, 3>& uv) {
  const Vec3 n = glm::cross(positions[1] - positions[0], positions[2] - positions[0]);
  // A triangle with no area has no normal and no sample worth taking. (NaN
  // coordinates pass this test and are reported by Finalize.)
  if (glm::dot(n, n) == 0.0f) {
    ++degenerate_;
    return;
  }
  for (int c = 0; c < 3; ++c) corners_.push_back(Corner{positions[c], uv[c]});
  materialOf_.push_back(material);
  objectOf_.push_back(currentObject_);
}

size_t SceneBuilder::AddInstances(Scene mesh, std::span<const RigidTransform> meshToWorld) {
  const uint32_t materialBase = uint32_t(materials_.size());
  const int32_t textureBase = int32_t(textures_.size());
  for (Material& m : mesh.materials) {
    if (m.albedoTexture >= 0) m.albedoTexture += textureBase;
    materials_.push_back(std::move(m));
  }
  for (Texture& t : mesh.textures) textures_.push_back(std::move(t));
  mesh.materials.clear();
  mesh.textures.clear();
  for (Triangle& t : mesh.triangles) t.material += materialBase;
  const size_t added = mesh.triangles.size() * meshToWorld.size();
  instanceTriangles_ += added;
  instancedMeshes_.push_back(InstancedMesh{std::move(mesh), {meshToWorld.begin(), meshToWorld.end()}});
  return added;
}

void SceneBuilder::AddQuad(const Vec3& corner, const Vec3& edge1, const Vec3& edge2,
                           uint32_t material) {
  const Vec3 p0 = corner, p1 = corner + edge1, p2 = corner + edge1 + edge2, p3 = corner + edge2;
  AddTriangle({p0, p1, p2}, material, {Vec2(0, 0), Vec2(1, 0), Vec2(1, 1)});
  AddTriangle({p0, p2, p3}, material, {Vec2(0, 0), Vec2(1, 1), Vec2(0, 1)});
}

namespace {

struct PositionKey {
  uint32_t x, y, z;
  uint32_t object;  // corners of different movable objects never weld
  bool operator==(const PositionKey&) const = default;
};
struct PositionKeyHash {
  size_t operator()(const PositionKey& k) const {
    return size_t(HashCombine(HashCombine(HashCombine(Mix64(k.x), k.y), k.z), k.object));
  }
};
PositionKey KeyOf(const Vec3& p, uint32_t object) {
  PositionKey k;
  k.object = object;
  // +0.0f folds -0 into +0 so that the two weld together.
  const float x = p.x + 0.0f, y = p.y + 0.0f, z = p.z + 0.0f;
  std::memcpy(&k.x, &x, 4);
  std::memcpy(&k.y, &y, 4);
  std::memcpy(&k.z, &z, 4);
  return k;
}

// A triangle's three welded corner positions, in a canonical rotation.
struct CornerTriple {
  uint32_t a, b, c;
  bool operator==(const CornerTriple&) const = default;
};
struct CornerTripleHash {
  size_t operator()(const CornerTriple& t) const { return size_t(HashCombine(HashCombine(Mix64(t.a), t.b), t.c)); }
};

// Union-find over the corners incident to one welded position.
struct DisjointSets {
  std::vector<uint32_t> parent;
  explicit DisjointSets(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0u); }
  uint32_t Find(uint32_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  }
  void Union(uint32_t a, uint32_t b) { parent[Find(a)] = Find(b); }
};

}  // namespace

// Copies every instanced mesh into `scene` at each of its places, between the
// builder's own static part ([0, staticTriangles), [0, staticVertices)) and
// the movable objects, whose ranges and vertex indices move up. In place:
// BuildInto reserved the room, so the scene's arrays do not exist twice (for
// 2 million triangles that is ~200 MB less at the peak of a load).
void SceneBuilder::PlaceInstances(Scene& scene, uint32_t staticTriangles, uint32_t staticVertices) {
  size_t addedTriangles = 0, addedVertices = 0;
  for (const InstancedMesh& m : instancedMeshes_) {
    addedTriangles += m.mesh.triangles.size() * m.meshToWorld.size();
    addedVertices += m.mesh.vertices.size() * m.meshToWorld.size();
  }
  const size_t oldTriangles = scene.triangles.size(), oldVertices = scene.vertices.size();
  scene.triangles.resize(oldTriangles + addedTriangles);
  scene.vertices.resize(oldVertices + addedVertices);
  // The movable objects' part moves up to make room, vertex indices too.
  std::move_backward(scene.triangles.begin() + staticTriangles, scene.triangles.begin() + oldTriangles,
                     scene.triangles.end());
  std::move_backward(scene.vertices.begin() + staticVertices, scene.vertices.begin() + oldVertices,
                     scene.vertices.end());
  for (size_t t = staticTriangles + addedTriangles; t < scene.triangles.size(); ++t)
    for (uint32_t& v : scene.triangles[t].v) v += uint32_t(addedVertices);
  for (MovableObject& o : objects_) {
    o.firstTriangle += uint32_t(addedTriangles);
    o.firstVertex += uint32_t(addedVertices);
  }
  scene.instances.clear();
  uint32_t nextTriangle = staticTriangles, nextVertex = staticVertices;
  for (const InstancedMesh& m : instancedMeshes_) {
    const uint32_t prototype = uint32_t(scene.instances.size());
    for (const RigidTransform& toWorld : m.meshToWorld) {
      StaticInstance instance;
      instance.firstTriangle = nextTriangle;
      instance.triangleCount = uint32_t(m.mesh.triangles.size());
      instance.firstVertex = nextVertex;
      instance.vertexCount = uint32_t(m.mesh.vertices.size());
      instance.prototype = prototype;
      instance.meshToWorld = toWorld;
      for (const Vertex& v : m.mesh.vertices)
        scene.vertices[nextVertex++] =
            Vertex{toWorld.ApplyPoint(v.position), glm::normalize(toWorld.ApplyVector(v.normal))};
      for (Triangle t : m.mesh.triangles) {
        for (uint32_t& v : t.v) v += instance.firstVertex;
        scene.triangles[nextTriangle++] = t;
      }
      scene.instances.push_back(instance);
    }
  }
  instancedMeshes_.clear();
  instanceTriangles_ = 0;
}

Status SceneBuilder::BuildInto(Scene& scene) {
  size_t triangleCount = corners_.size() / 3;
  if (triangleCount == 0) {
    const std::string where = scene.sourcePath.empty() ? scene.name : scene.sourcePath.string();
    return Fail(degenerate_ > 0
                    ? fmt::format("{}: the mesh has no triangles with area ({} degenerate ones dropped)",
                                  where, degenerate_)
                    : fmt::format("{}: the mesh has no triangles", where));
  }

  // 0. Static triangles first, then each movable object's, keeping the order
  // within each part: every part becomes one contiguous range.
  if (!objects_.empty()) {
    std::vector<uint32_t> order(triangleCount);
    std::iota(order.begin(), order.end(), 0u);
    const auto partOf = [&](uint32_t t) { return objectOf_[t] == kStaticObject ? 0u : objectOf_[t] + 1u; };
    std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return partOf(a) < partOf(b); });
    std::vector<Corner> corners(corners_.size());
    std::vector<uint32_t> materialOf(triangleCount), objectOf(triangleCount);
    for (size_t i = 0; i < triangleCount; ++i) {
      for (int c = 0; c < 3; ++c) corners[3 * i + c] = corners_[3 * order[i] + c];
      materialOf[i] = materialOf_[order[i]];
      objectOf[i] = objectOf_[order[i]];
    }
    corners_ = std::move(corners);
    materialOf_ = std::move(materialOf);
    objectOf_ = std::move(objectOf);
  }

  // 1. Weld corners by exact position, within each part.
  std::unordered_map<PositionKey, uint32_t, PositionKeyHash> positionIndex;
  positionIndex.reserve(corners_.size());
  std::vector<uint32_t> positionOfCorner(corners_.size());
  std::vector<Vec3> positions;
  for (size_t c = 0; c < corners_.size(); ++c) {
    auto [it, inserted] =
        positionIndex.try_emplace(KeyOf(corners_[c].position, objectOf_[c / 3]), uint32_t(positions.size()));
    if (inserted) positions.push_back(corners_[c].position);
    positionOfCorner[c] = it->second;
  }

  // 1b. A triangle whose welded corners repeat an earlier one's in the same
  // cyclic order is the same surface listed twice (the Cornell box's tall box
  // lists its front face twice). Keep the first: two coincident copies would
  // each be refined, and visibility would show pieces of both, leaving
  // T-vertices between them; they would also count twice in vertex normals.
  {
    std::unordered_set<CornerTriple, CornerTripleHash> seen;
    seen.reserve(triangleCount);
    size_t kept = 0;
    for (size_t t = 0; t < triangleCount; ++t) {
      const uint32_t* p = &positionOfCorner[3 * t];
      // Rotate so the smallest index leads: the same cyclic order (the same
      // orientation) gives the same key, the reverse order does not.
      const int first = p[0] <= p[1] && p[0] <= p[2] ? 0 : (p[1] <= p[2] ? 1 : 2);
      if (!seen.insert(CornerTriple{p[first], p[(first + 1) % 3], p[(first + 2) % 3]}).second) {
        ++duplicates_;
        continue;
      }
      for (int c = 0; c < 3; ++c) {
        corners_[3 * kept + c] = corners_[3 * t + c];
        positionOfCorner[3 * kept + c] = positionOfCorner[3 * t + c];
      }
      materialOf_[kept] = materialOf_[t];
      objectOf_[kept] = objectOf_[t];
      ++kept;
    }
    triangleCount = kept;
    corners_.resize(3 * kept);
    positionOfCorner.resize(3 * kept);
    materialOf_.resize(kept);
    objectOf_.resize(kept);
  }

  // 2. Face normals, and the interior angle at every corner (the weight of
  // that face in the vertex normal: angle weighting is independent of how a
  // surface happens to be triangulated).
  std::vector<Vec3> faceNormal(triangleCount);
  std::vector<float> cornerAngle(corners_.size());
  for (size_t t = 0; t < triangleCount; ++t) {
    const Vec3& p0 = corners_[3 * t].position;
    const Vec3& p1 = corners_[3 * t + 1].position;
    const Vec3& p2 = corners_[3 * t + 2].position;
    faceNormal[t] = glm::normalize(glm::cross(p1 - p0, p2 - p0));
    const Vec3 p[3] = {p0, p1, p2};
    for (int c = 0; c < 3; ++c) {
      const Vec3 a = p[(c + 1) % 3] - p[c];
      const Vec3 b = p[(c + 2) % 3] - p[c];
      const float denom = glm::length(a) * glm::length(b);
      cornerAngle[3 * t + c] = denom > 0.0f ? std::acos(std::clamp(glm::dot(a, b) / denom, -1.0f, 1.0f)) : 0.0f;
    }
  }

  // 3. Corners incident to each position (CSR layout).
  std::vector<uint32_t> start(positions.size() + 1, 0);
  for (uint32_t p : positionOfCorner) ++start[p + 1];
  std::partial_sum(start.begin(), start.end(), start.begin());
  std::vector<uint32_t> incident(corners_.size());
  {
    std::vector<uint32_t> fill(start.begin(), start.end() - 1);
    for (uint32_t c = 0; c < corners_.size(); ++c) incident[fill[positionOfCorner[c]]++] = c;
  }

  // 4. At each position, faces that share an edge through it and whose
  // normals are within the crease angle are one smooth sheet and share a
  // vertex; every other group gets its own vertex.
  std::vector<uint32_t> vertexOfCorner(corners_.size());
  std::vector<Vertex> vertices;
  // Room for the instances' copies too (PlaceInstances works in place).
  size_t instanceVertices = 0;
  for (const InstancedMesh& m : instancedMeshes_) instanceVertices += m.mesh.vertices.size() * m.meshToWorld.size();
  vertices.reserve(positions.size() + positions.size() / 4 + instanceVertices);
  for (uint32_t p = 0; p < positions.size(); ++p) {
    const uint32_t begin = start[p], end = start[p + 1];
    const uint32_t k = end - begin;
    DisjointSets sets(k);
    for (uint32_t i = 0; i < k; ++i) {
      const uint32_t ci = incident[begin + i];
      const uint32_t ti = ci / 3;
      for (uint32_t j = i + 1; j < k; ++j) {
        const uint32_t cj = incident[begin + j];
        const uint32_t tj = cj / 3;
        if (glm::dot(faceNormal[ti], faceNormal[tj]) < cosCrease_) continue;
        // Adjacent around p: the two faces share a second position.
        bool adjacent = false;
        for (int a = 0; a < 3 && !adjacent; ++a) {
          const uint32_t pa = positionOfCorner[3 * ti + a];
          if (pa == p) continue;
          for (int b = 0; b < 3; ++b)
            if (positionOfCorner[3 * tj + b] == pa) adjacent = true;
        }
        if (adjacent) sets.Union(i, j);
      }
    }
    std::vector<int64_t> vertexOfRoot(k, -1);
    for (uint32_t i = 0; i < k; ++i) {
      const uint32_t root = sets.Find(i);
      if (vertexOfRoot[root] < 0) {
        vertexOfRoot[root] = int64_t(vertices.size());
        vertices.push_back(Vertex{positions[p], Vec3(0.0f)});
      }
      const uint32_t c = incident[begin + i];
      Vertex& v = vertices[size_t(vertexOfRoot[root])];
      v.normal += cornerAngle[c] * faceNormal[c / 3];
      vertexOfCorner[c] = uint32_t(vertexOfRoot[root]);
    }
  }
  for (uint32_t c = 0; c < corners_.size(); ++c) {
    Vertex& v = vertices[vertexOfCorner[c]];
    const float len = glm::length(v.normal);
    // A zero sum cannot happen within a crease angle below 90 degrees, but a
    // caller may ask for 180: fall back to the face's own normal.
    if (!(len > 1e-20f)) v.normal = faceNormal[c / 3];
  }
  for (Vertex& v : vertices) {
    const float len = glm::length(v.normal);
    if (len > 0.0f) v.normal /= len;
  }

  scene.vertices = std::move(vertices);
  scene.triangles.clear();
  scene.triangles.reserve(triangleCount + instanceTriangles_);
  scene.triangles.resize(triangleCount);
  for (size_t t = 0; t < triangleCount; ++t) {
    Triangle& tri = scene.triangles[t];
    for (int c = 0; c < 3; ++c) {
      tri.v[c] = vertexOfCorner[3 * t + c];
      tri.uv[c] = corners_[3 * t + c].uv;
    }
    tri.material = materialOf_[t];
  }
  scene.materials = std::move(materials_);
  scene.textures = std::move(textures_);
  // Object ranges: triangles are sorted by part, and so are the vertices
  // (positions were numbered in corner order, and vertices in position order).
  for (MovableObject& o : objects_) o.triangleCount = o.vertexCount = 0;
  for (uint32_t t = 0; t < triangleCount; ++t) {
    if (objectOf_[t] == kStaticObject) continue;
    MovableObject& o = objects_[objectOf_[t]];
    if (o.triangleCount++ == 0) o.firstTriangle = t;
    const uint32_t lo = *std::min_element(scene.triangles[t].v.begin(), scene.triangles[t].v.end());
    const uint32_t hi = *std::max_element(scene.triangles[t].v.begin(), scene.triangles[t].v.end());
    if (o.vertexCount == 0) {
      o.firstVertex = lo;
      o.vertexCount = hi - lo + 1;
    } else {
      const uint32_t end = std::max(o.firstVertex + o.vertexCount, hi + 1);
      o.firstVertex = std::min(o.firstVertex, lo);
      o.vertexCount = end - o.firstVertex;
    }
  }
  for (const MovableObject& o : objects_)
    if (o.triangleCount == 0) return Fail(fmt::format("movable object '{}' has no triangles with area", o.name));
  if (!instancedMeshes_.empty()) {
    // Static triangles (and their vertices) come first.
    const uint32_t staticTriangles =
        uint32_t(std::count(objectOf_.begin(), objectOf_.begin() + triangleCount, kStaticObject));
    uint32_t staticVertices = uint32_t(scene.vertices.size());
    for (const MovableObject& o : objects_) staticVertices = std::min(staticVertices, o.firstVertex);
    PlaceInstances(scene, staticTriangles, staticVertices);
  } else {
    scene.instances.clear();
  }
  scene.objects = std::move(objects_);
  corners_.clear();
  materialOf_.clear();
  objectOf_.clear();
  objects_.clear();
  currentObject_ = kStaticObject;
  return scene.Finalize();
}

}  // namespace penumbra
