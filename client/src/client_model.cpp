#include "penumbra/client/client_model.h"

#include <fmt/format.h>

#include "penumbra/common/logging.h"
#include "penumbra/wire.pb.h"

namespace penumbra::client {

namespace {
constexpr uint32_t kMaxTextureSide = 16384;
}

ClientModel::ClientModel() : log_(Logger("client")) {}

void ClientModel::Apply(std::vector<SessionEvent> events, SessionRequests& requests) {
  for (SessionEvent& event : events) {
    if (auto* connected = std::get_if<Connected>(&event)) {
      OnConnected(std::move(*connected));
    } else if (auto* error = std::get_if<SmaErrorReceived>(&event)) {
      // Connection 0: a move that could not be sent at all.
      if (error->connection == 0 || error->connection == connection_) smaErrors_.push_back(std::move(*error));
    } else if (const auto* disconnected = std::get_if<Disconnected>(&event)) {
      // The last image stays on screen until the next connection replaces it.
      if (disconnected->connection == connection_) online_ = false;
    } else if (!online_) {
      continue;  // a connection that ended or was abandoned
    } else if (const auto* delta = std::get_if<DeltaReceived>(&event)) {
      if (delta->connection == connection_) OnDelta(*delta, requests);
    } else if (auto* texture = std::get_if<TextureReceived>(&event)) {
      if (texture->connection == connection_) OnTexture(std::move(*texture), requests);
    } else if (const auto* counters = std::get_if<SmaCountersReceived>(&event)) {
      if (counters->connection == connection_) OnCounters(*counters);
    }
  }
}

void ClientModel::OnConnected(Connected&& event) {
  // Without an identity (hash 0) nothing proves it is the same scene.
  const bool sameScene = scene_ && event.scene.identity != 0 && event.scene.identity == scene_->identity;
  if (!sameScene) {
    ++sceneGeneration_;
    texturesReceived_.clear();
    texturesToUpload_.clear();
  }
  scene_ = std::move(event.scene);
  connection_ = event.connection;
  online_ = true;
  deltaViewSerial_ = 0;
  smaReport_.reset();
  // Requests made on an earlier connection will not be answered.
  texturesRequested_ = texturesReceived_;
  ResetMesh();
}

void ClientModel::ResetMesh() {
  std::vector<RigidTransform> objectToWorld;
  objectToWorld.reserve(scene_->objects.size());
  for (const ClientObject& o : scene_->objects) objectToWorld.push_back(o.objectToWorld);
  mesh_.Reset(scene_->MaterialTextures(), scene_->textureCount, objectToWorld, scene_->sceneEpoch);
  std::vector<Bounds3> spaceBounds{scene_->bounds};
  for (const ClientObject& o : scene_->objects) spaceBounds.push_back(o.objectBounds);
  // The SceneInfo's bounds were checked when it was read; a scene without
  // geometry (empty bounds) leaves new vertices unchecked -- it sends none.
  if (auto ok = mesh_.SetVertexBounds(spaceBounds); !ok) log_->warn("vertex positions unchecked: {}", ok.error().message);
}

void ClientModel::OnDelta(const DeltaReceived& event, SessionRequests& requests) {
  const wire::Delta& d = *event.delta;
  if (auto ok = mesh_.Apply(d); !ok) return Abandon(ok.error().message, requests);
  if (d.kind() == wire::DELTA_KIND_MOVED) {
    // The scene's objects stay where the SMA says they are now.
    for (uint32_t id : d.moved_objects()) scene_->objects[id - 1].objectToWorld = mesh_.ConfirmedTransform(id);
    scene_->sceneEpoch = mesh_.SceneEpoch();
    log_->debug("delta {}: {} object(s) moved, scene epoch {}", d.sequence(), d.moved_objects_size(),
                mesh_.SceneEpoch());
  }
  log_->debug("delta {} ({}) for view {}: -{} +{} triangles, +{} vertices; {} held, {} samples pending{}", d.sequence(),
              wire::DeltaKind_Name(d.kind()), d.view_id(), d.removed_triangles_size(), d.triangle_ids_size(),
              d.vertex_ids_size(), mesh_.TriangleCount(), d.pending_samples(), d.converged() ? ", converged" : "");
  // A MOVED sent before the SMA had any view of ours answers none.
  if (!(d.kind() == wire::DELTA_KIND_MOVED && d.view_id() == 0)) deltaViewSerial_ = event.viewSerial;
  RequestNeededTextures(requests);
}

void ClientModel::OnTexture(TextureReceived&& event, SessionRequests& requests) {
  const TextureReceived& t = event;
  if (!texturesRequested_.contains(t.texture) || texturesReceived_.contains(t.texture))
    return Abandon(fmt::format("texture {} was not asked for", t.texture), requests);
  if (t.width == 0 || t.height == 0 || t.width > kMaxTextureSide || t.height > kMaxTextureSide ||
      t.rgb8.size() != size_t(t.width) * size_t(t.height) * 3)
    return Abandon(fmt::format("texture {}: {}x{} texels but {} bytes of rgb8", t.texture, t.width, t.height,
                               t.rgb8.size()),
                   requests);
  texturesReceived_.insert(t.texture);
  log_->debug("texture {} received: {}x{}", t.texture, t.width, t.height);
  texturesToUpload_.push_back(ReceivedTexture{t.texture, int(t.width), int(t.height), std::move(event.rgb8)});
}

void ClientModel::OnCounters(const SmaCountersReceived& event) {
  auto triangles = event.counters.find("client_triangles_held");
  auto vertices = event.counters.find("client_vertices_held");
  if (triangles == event.counters.end() || vertices == event.counters.end()) return;
  SmaReport report;
  report.trianglesHeld = uint64_t(triangles->second);
  report.verticesHeld = uint64_t(vertices->second);
  report.agrees = report.trianglesHeld == mesh_.TriangleCount() && report.verticesHeld == mesh_.VertexCount();
  report.atSequence = mesh_.LastSequence();
  if (!report.agrees && (!smaReport_ || smaReport_->agrees))
    log_->warn("the SMA believes this client holds {} triangles and {} vertices; it holds {} and {}",
               report.trianglesHeld, report.verticesHeld, mesh_.TriangleCount(), mesh_.VertexCount());
  smaReport_ = report;
}

void ClientModel::Abandon(const std::string& reason, SessionRequests& requests) {
  ++protocolErrors_;
  log_->error("connection {}: {}; emptying the mesh and reconnecting", connection_, reason);
  requests.AbandonConnection(connection_, reason);
  online_ = false;
  ResetMesh();
}

void ClientModel::RequestNeededTextures(SessionRequests& requests) {
  for (const TriangleGroup& group : mesh_.Groups()) {
    if (group.texture < 0 || group.allocator.Live() == 0) continue;
    if (texturesRequested_.insert(uint32_t(group.texture)).second) {
      log_->debug("requesting texture {}", group.texture);
      requests.RequestTexture(connection_, uint32_t(group.texture));
    }
  }
}

bool ClientModel::NeededTexturesArrived() const {
  for (const TriangleGroup& group : mesh_.Groups())
    if (group.texture >= 0 && group.allocator.Live() > 0 && !texturesReceived_.contains(uint32_t(group.texture)))
      return false;
  return true;
}

std::vector<ReceivedTexture> ClientModel::TakeTextures() { return std::exchange(texturesToUpload_, {}); }

bool ClientModel::Converged(uint64_t viewSerial) const {
  return online_ && viewSerial != 0 && deltaViewSerial_ == viewSerial && mesh_.Converged() && NeededTexturesArrived();
}

}  // namespace penumbra::client
