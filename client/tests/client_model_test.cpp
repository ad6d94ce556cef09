// ClientModel: session events applied on the render thread. A bad delta
// empties the mesh and abandons its connection, whose later events are
// ignored; the next connection starts clean. Textures are asked for once,
// when a triangle first needs them; convergence waits for them.

#include "penumbra/client/client_model.h"

#include <gtest/gtest.h>

#include "support/delta_builder.h"
#include "support/fake_sma.h"

namespace penumbra::client {
namespace {

using testing::DeltaBuilder;

struct RecordedRequests : SessionRequests {
  void RequestTexture(uint64_t connection, uint32_t texture) override {
    textureRequests.emplace_back(connection, texture);
  }
  void AbandonConnection(uint64_t connection, const std::string& reason) override {
    abandoned.emplace_back(connection, reason);
  }
  std::vector<std::pair<uint64_t, uint32_t>> textureRequests;
  std::vector<std::pair<uint64_t, std::string>> abandoned;
};

Connected MakeConnected(uint64_t connection, uint64_t sceneHash = 7) {
  Connected c;
  c.connection = connection;
  c.scene = testing::UnitSquareScene(sceneHash);
  return c;
}

// One grey triangle (sequence, view serial as given).
DeltaReceived GreyTriangle(uint64_t connection, uint64_t sequence, uint64_t serial, bool converged = true) {
  DeltaBuilder d(sequence, 1);
  d.Vertex(1, Vec3(0), Rgb(1)).Vertex(2, Vec3(1, 0, 0), Rgb(1)).Vertex(3, Vec3(0, 1, 0), Rgb(1));
  d.Triangle(10, {1, 2, 3}, 0).Converged(converged);
  return DeltaReceived{connection, serial, d.Shared()};
}

DeltaReceived TexturedTriangle(uint64_t connection, uint64_t sequence, uint64_t serial) {
  DeltaBuilder d(sequence, 1);
  d.Vertex(4, Vec3(0), Rgb(1)).Vertex(5, Vec3(1, 0, 0), Rgb(1)).Vertex(6, Vec3(0, 1, 0), Rgb(1));
  d.Triangle(20, {4, 5, 6}, 1, std::array<float, 6>{0, 0, 1, 0, 0, 1}).Converged();
  return DeltaReceived{connection, serial, d.Shared()};
}

TextureReceived Texture(uint64_t connection, uint32_t width, uint32_t height, size_t bytes) {
  TextureReceived t;
  t.connection = connection;
  t.texture = 0;
  t.width = width;
  t.height = height;
  t.rgb8 = std::string(bytes, '\x80');
  return t;
}

template <class... E>
std::vector<SessionEvent> Events(E&&... events) {
  std::vector<SessionEvent> v;
  (v.emplace_back(std::forward<E>(events)), ...);
  return v;
}

TEST(ClientModelTest, ABadDeltaEmptiesTheMeshAndTheNextConnectionStartsClean) {
  ClientModel model;
  RecordedRequests requests;
  model.Apply(Events(MakeConnected(1), GreyTriangle(1, 1, 1)), requests);
  ASSERT_EQ(model.Mesh().TriangleCount(), 1u);
  EXPECT_TRUE(model.Converged(1));

  // Adds a good triangle, then one whose vertex was never sent.
  DeltaBuilder bad(2, 1, wire::DELTA_KIND_SHADED);
  bad.Vertex(7, Vec3(0.5f, 0.5f, 0), Rgb(1)).Triangle(11, {1, 2, 7}, 0).Triangle(12, {1, 2, 99}, 0);
  model.Apply(Events(DeltaReceived{1, 1, bad.Shared()}, GreyTriangle(1, 3, 1)), requests);
  ASSERT_EQ(requests.abandoned.size(), 1u);
  EXPECT_EQ(requests.abandoned[0].first, 1u);
  EXPECT_NE(requests.abandoned[0].second.find("vertex 99"), std::string::npos) << requests.abandoned[0].second;
  EXPECT_FALSE(model.Online());
  EXPECT_EQ(model.Mesh().TriangleCount(), 0u) << "nothing of a suspect mesh stays";
  EXPECT_EQ(model.ProtocolErrors(), 1u);
  EXPECT_FALSE(model.Converged(1));

  // The reconnection's first delta (sequence 1 again) applies to an empty mesh.
  model.Apply(Events(Disconnected{1, "refused a delta"}, MakeConnected(2), GreyTriangle(2, 1, 1)), requests);
  EXPECT_TRUE(model.Online());
  EXPECT_EQ(model.Mesh().TriangleCount(), 1u);
  EXPECT_EQ(model.Mesh().VertexCount(), 3u);
  EXPECT_EQ(requests.abandoned.size(), 1u);
  EXPECT_TRUE(model.Converged(1));
}

TEST(ClientModelTest, ALostConnectionKeepsTheImageUntilTheNextOneReplacesIt) {
  ClientModel model;
  RecordedRequests requests;
  model.Apply(Events(MakeConnected(1), GreyTriangle(1, 1, 1), Disconnected{1, "peer closed"}), requests);
  EXPECT_FALSE(model.Online());
  EXPECT_EQ(model.Mesh().TriangleCount(), 1u);
  EXPECT_FALSE(model.Converged(1));
  // Late events of the ended connection are ignored.
  model.Apply(Events(GreyTriangle(1, 2, 1)), requests);
  EXPECT_TRUE(requests.abandoned.empty());
  model.Apply(Events(MakeConnected(2)), requests);
  EXPECT_EQ(model.Mesh().TriangleCount(), 0u);
  EXPECT_EQ(model.SceneGeneration(), 1u) << "same scene identity";
  model.Apply(Events(MakeConnected(3, /*sceneHash=*/8)), requests);
  EXPECT_EQ(model.SceneGeneration(), 2u) << "another scene";
}

TEST(ClientModelTest, ConvergedOnlyForTheLatestViewSerial) {
  ClientModel model;
  RecordedRequests requests;
  model.Apply(Events(MakeConnected(1), GreyTriangle(1, 1, /*serial=*/0)), requests);
  EXPECT_FALSE(model.Converged(1)) << "a delta for an older view";
  model.Apply(Events(MakeConnected(2), GreyTriangle(2, 1, 3, /*converged=*/false)), requests);
  EXPECT_FALSE(model.Converged(3));
  model.Apply(Events(DeltaReceived{2, 3, DeltaBuilder(2, 1, wire::DELTA_KIND_STATUS).Converged().Shared()}), requests);
  EXPECT_TRUE(model.Converged(3));
  EXPECT_FALSE(model.Converged(4));
}

TEST(ClientModelTest, TexturesAreAskedForOnceAndConvergenceWaitsForThem) {
  ClientModel model;
  RecordedRequests requests;
  model.Apply(Events(MakeConnected(1), TexturedTriangle(1, 1, 1)), requests);
  ASSERT_EQ(requests.textureRequests.size(), 1u);
  EXPECT_EQ(requests.textureRequests[0], std::make_pair(uint64_t(1), 0u));
  EXPECT_FALSE(model.Converged(1)) << "the texture has not arrived";

  // After a reconnection the unanswered request is made again, once.
  model.Apply(Events(Disconnected{1, "lost"}, MakeConnected(2), TexturedTriangle(2, 1, 1)), requests);
  ASSERT_EQ(requests.textureRequests.size(), 2u);
  EXPECT_EQ(requests.textureRequests[1].first, 2u);
  model.Apply(Events(Texture(2, 2, 2, 12)), requests);
  EXPECT_TRUE(model.Converged(1));
  auto textures = model.TakeTextures();
  ASSERT_EQ(textures.size(), 1u);
  EXPECT_EQ(textures[0].width, 2);
  EXPECT_TRUE(model.TakeTextures().empty());

  // A texture received survives a reconnection to the same scene.
  model.Apply(Events(Disconnected{2, "lost"}, MakeConnected(3), TexturedTriangle(3, 1, 1)), requests);
  EXPECT_EQ(requests.textureRequests.size(), 2u);
  EXPECT_TRUE(model.Converged(1));
}

TEST(ClientModelTest, ATextureOfTheWrongSizeIsAProtocolError) {
  ClientModel model;
  RecordedRequests requests;
  model.Apply(Events(MakeConnected(1), TexturedTriangle(1, 1, 1), Texture(1, 2, 2, 11)), requests);
  ASSERT_EQ(requests.abandoned.size(), 1u);
  EXPECT_NE(requests.abandoned[0].second.find("2x2 texels but 11 bytes"), std::string::npos);
  EXPECT_TRUE(model.TakeTextures().empty());
}

TEST(ClientModelTest, ComparesTheSmaCountersWithWhatItHolds) {
  ClientModel model;
  RecordedRequests requests;
  model.Apply(Events(MakeConnected(1), GreyTriangle(1, 1, 1),
                     SmaCountersReceived{1, {{"client_triangles_held", 1}, {"client_vertices_held", 3}}}),
              requests);
  ASSERT_TRUE(model.LastSmaReport().has_value());
  EXPECT_TRUE(model.LastSmaReport()->agrees);
  EXPECT_EQ(model.LastSmaReport()->atSequence, 1u);
  model.Apply(Events(SmaCountersReceived{1, {{"client_triangles_held", 2}, {"client_vertices_held", 3}}}), requests);
  EXPECT_FALSE(model.LastSmaReport()->agrees);
}

// Issue 14: a scene with a movable object. A MOVED delta moves it in the
// scene and the mesh, a bad one abandons the connection like any bad delta
// (and the mesh is emptied with the object where the SMA last had it), and
// a refused move passes through for the HUD.
TEST(ClientModelTest, MovedDeltasKeepTheScenesObjectsWhereTheSmaHasThem) {
  ClientModel model;
  RecordedRequests requests;
  Connected connected = MakeConnected(1);
  connected.scene.objects.push_back(ClientObject{"box", Bounds3{}, RigidTransform::Identity(), false});
  connected.scene.sceneEpoch = 2;
  DeltaBuilder d(1, 1);
  d.Vertex(1, Vec3(0), Rgb(1)).Vertex(2, Vec3(1, 0, 0), Rgb(1)).Vertex(3, Vec3(0, 1, 0), Rgb(1));
  d.Triangle(10, {1, 2, 3}, 0);
  for (int i = 0; i < 3; ++i) d.Mutable().add_vertex_objects(1);
  model.Apply(Events(std::move(connected), DeltaReceived{1, 1, d.Shared()}), requests);
  ASSERT_EQ(model.Mesh().TriangleCount(), 1u);
  EXPECT_EQ(model.Mesh().SceneEpoch(), 2u);

  const RigidTransform moved = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.5f, Vec3(4, 5, 6));
  DeltaBuilder move(2, 1, wire::DELTA_KIND_MOVED);
  move.Mutable().set_scene_epoch(3);
  move.Mutable().add_moved_objects(1);
  for (float v : moved.ToRowMajor()) move.Mutable().add_moved_object_transforms(v);
  model.Apply(Events(DeltaReceived{1, 1, move.Shared()},
                     SmaErrorReceived{1, kMoveRequestBit | 4, true, "SMA x reports INVALID_REQUEST: animated"}),
              requests);
  EXPECT_TRUE(requests.abandoned.empty());
  EXPECT_EQ(model.Scene()->sceneEpoch, 3u);
  EXPECT_EQ(model.Scene()->objects[0].objectToWorld.translation, Vec3(4, 5, 6));
  const Vec3 world = *model.Mesh().WorldPosition(2);
  const Vec3 expected = moved.ApplyPoint(Vec3(1, 0, 0));
  EXPECT_NEAR(glm::length(world - expected), 0.0f, 1e-5f);
  const auto errors = model.TakeSmaErrors();
  ASSERT_EQ(errors.size(), 1u);
  EXPECT_TRUE(errors[0].move);
  EXPECT_TRUE(model.TakeSmaErrors().empty());

  // A MOVED naming an object the scene lacks is a protocol violation.
  DeltaBuilder unknown(3, 1, wire::DELTA_KIND_MOVED);
  unknown.Mutable().set_scene_epoch(3);
  unknown.Mutable().add_moved_objects(2);
  for (float v : moved.ToRowMajor()) unknown.Mutable().add_moved_object_transforms(v);
  model.Apply(Events(DeltaReceived{1, 1, unknown.Shared()}), requests);
  ASSERT_EQ(requests.abandoned.size(), 1u);
  EXPECT_NE(requests.abandoned[0].second.find("moves object 2"), std::string::npos) << requests.abandoned[0].second;
  EXPECT_EQ(model.Mesh().TriangleCount(), 0u);
  EXPECT_EQ(model.Mesh().ConfirmedTransform(1).translation, Vec3(4, 5, 6)) << "emptied, the object stays moved";
}

}  // namespace
}  // namespace penumbra::client
