// Issue 14's correctness checks, on real processes: after a move and
// convergence, what the clients hold equals what a fresh stack computes with
// the object already at its new place (so the invalidation left nothing
// stale, item 5 a and b); two clients both see the move (c); a bad move is
// refused and changes nothing (d); a renderer killed during a move loses no
// update (e).
//
// Vertices are compared by place, not by id: the two stacks refine
// differently, but a vertex at the same object-space point with the same
// normal, on the same part of the scene, is the same sample.

#include <signal.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <thread>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "penumbra/common/rigid_transform.h"
#include "support/service.h"
#include "support/sma_client.h"
#include "support/wire_client.h"

namespace penumbra::testing {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

const std::string kScenesDir = std::string(PENUMBRA_SOURCE_DIR) + "/scenes";
const std::string kFloating = kScenesDir + "/cornell-box-floating.json";
const std::string kAnimated = kScenesDir + "/cornell-box-animated.json";
constexpr int kWidth = 128;
constexpr int kHeight = 96;
// The move every test makes: the box slides 0.3 along +x and rises 0.1, so
// its shadow on the floor moves by about its own width.
const Vec3 kMoveBy(0.3f, 0.1f, 0.0f);

Service MustStart(const std::string& exe, const std::vector<std::string>& args, const std::string& tag) {
  auto s = StartService(exe, args, tag);
  EXPECT_TRUE(s.ok()) << s.error().message;
  return s.ok() ? std::move(*s) : Service{};
}

struct Stack {
  std::vector<Service> renderers;
  Service sma;
};

// Renderers with few bounces (fast) and an SMA that refines a little and
// improves displayed samples until their standard error is below 3 %, so
// converged radiance is comparable across stacks within a stated noise.
Stack StartStack(const std::string& scene, int rendererCount, const std::string& tag,
                 const std::vector<std::string>& extraSmaArgs = {}) {
  Stack stack;
  std::vector<std::string> smaArgs = {"--scene", scene, "--criterion", "nld_os", "--max-refine-depth", "2",
                                      "--improve-target-error", "0.03", "--improve-max-paths", "2048"};
  smaArgs.insert(smaArgs.end(), extraSmaArgs.begin(), extraSmaArgs.end());
  for (int i = 0; i < rendererCount; ++i) {
    stack.renderers.push_back(MustStart(PENUMBRA_RENDERER_EXE,
                                        {"--scene", scene, "--threads", "1", "--spp", "32", "--max-bounces", "2"},
                                        fmt::format("{}-renderer{}", tag, i)));
    smaArgs.insert(smaArgs.end(), {"--renderer", stack.renderers.back().Address()});
  }
  stack.sma = MustStart(PENUMBRA_SMA_EXE, smaArgs, tag + "-sma");
  return stack;
}

const wire::MovableObjectInfo* FindObject(const wire::SceneInfo& info, const std::string& name) {
  for (const auto& o : info.objects())
    if (o.name() == name) return &o;
  return nullptr;
}

RigidTransform TransformOf(const wire::MovableObjectInfo& o) {
  std::vector<float> m(o.object_to_world().begin(), o.object_to_world().end());
  auto t = RigidTransform::FromRowMajor(m);
  EXPECT_TRUE(t.ok()) << (t.ok() ? "" : t.error().message);
  return t.ok() ? *t : RigidTransform{};
}

wire::Envelope MoveEnvelope(uint64_t requestId, uint32_t object, std::span<const float> m12) {
  wire::Envelope e;
  auto* move = e.mutable_move_object();
  move->set_request_id(requestId);
  move->set_object(object);
  for (float v : m12) move->add_object_to_world(v);
  return e;
}

// Receives until a delta with kind MOVED and scene_epoch >= `epoch` has been
// applied (unless `needMoved` is false), then until a converged delta of
// `viewId` at that epoch or later.
Status WaitMovedAndConverged(SmaTestClient& c, uint64_t viewId, uint64_t epoch, std::chrono::milliseconds timeout,
                             bool* sawMoved = nullptr, uint64_t* reshadedUpdates = nullptr, bool needMoved = true) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  bool moved = !needMoved;
  bool converged = false;
  uint64_t updates = 0;
  auto lastHeartbeat = std::chrono::steady_clock::now();
  while (!(moved && converged)) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= deadline)
      return Fail(fmt::format("after the move to epoch {}: moved {}, converged {} (view {}, {} pending)", epoch, moved,
                              converged, c.Mesh().LastViewId(), c.Mesh().PendingSamples()));
    if (now - lastHeartbeat > 3s) {
      wire::Envelope heartbeat;
      heartbeat.mutable_heartbeat()->set_sent_unix_ms(1);
      c.Wire().Send(heartbeat);
      lastHeartbeat = now;
    }
    auto e = c.Wire().Receive(500ms);
    if (!e && e.error().message == "timeout") continue;
    if (!e) return e.error();
    if (e->has_delta()) {
      const wire::Delta& d = e->delta();
      if (d.kind() == wire::DELTA_KIND_MOVED && d.scene_epoch() >= epoch) moved = true;
      if (d.kind() == wire::DELTA_KIND_RESHADED) updates += uint64_t(d.updated_vertex_ids_size());
      if (moved && d.view_id() == viewId && d.converged() && d.scene_epoch() >= epoch) converged = true;
    }
    if (auto ok = c.Apply(*e); !ok) return ok;
  }
  if (sawMoved) *sawMoved = moved;
  if (reshadedUpdates) *reshadedUpdates = updates;
  return Status::Ok();
}

// A held vertex's identity across stacks: its part of the scene and its
// object-space position and normal, rounded to 1e-4.
struct PlaceKey {
  uint32_t object;
  std::array<int64_t, 3> position;
  auto operator<=>(const PlaceKey&) const = default;
};

struct HeldSample {
  Rgb radiance;
  Vec3 normal;
};

// The object each held vertex belongs to comes from the deltas' vertex_objects;
// HeldMesh keeps positions as sent (object space for object vertices).
std::multimap<PlaceKey, HeldSample> SamplesByPlace(SmaTestClient& c) {
  std::multimap<PlaceKey, HeldSample> out;
  for (const auto& [id, v] : c.Mesh().Vertices()) {
    PlaceKey key{v.object, {std::llround(v.position.x * 1e4), std::llround(v.position.y * 1e4),
                            std::llround(v.position.z * 1e4)}};
    out.emplace(key, HeldSample{v.radiance, Vec3(0.0f)});
  }
  return out;
}

struct Agreement {
  size_t compared = 0;
  size_t outside = 0;        // beyond the per-vertex tolerance
  double meanRelative = 0.0;  // mean |a - b| / max(a, b, floor) over compared vertices
  std::string worst;
};

// Two converged estimates of the same sample each carry a relative standard
// error below 3 % (the SMA's --improve-target-error); their difference has a
// standard deviation below 3 % * sqrt(2) = 4.3 % of the value, so 5 sigma is
// about 21 %. A stale sample -- lit where the box now shadows it, or
// shadowed where it no longer is -- differs by far more. A floor of 2 % of
// the brightest value keeps near-black samples from failing on noise.
Agreement Compare(const std::multimap<PlaceKey, HeldSample>& moved, const std::multimap<PlaceKey, HeldSample>& fresh) {
  Agreement a;
  float brightest = 0.0f;
  for (const auto& [k, s] : fresh) brightest = std::max(brightest, Luminance(s.radiance));
  const float floor = 0.02f * brightest;
  const auto relativeDifference = [floor](float la, float lb) {
    return double(std::abs(la - lb)) / std::max({la, lb, floor});
  };
  double worstRel = 0.0;
  // Several vertices can share a place (the two sides of a surface; the
  // faces meeting at a corner, each with its own normal), and the two
  // stacks need not hold the same ones there (their refinement differs by
  // noise, and with it which leaves touch a corner). At each place, pair
  // the two stacks' samples one to one, closest pair first, and compare the
  // pairs; a sample left without a partner has nothing to be compared with.
  for (auto it = moved.begin(); it != moved.end(); it = moved.upper_bound(it->first)) {
    const PlaceKey& key = it->first;
    auto [mlo, mhi] = moved.equal_range(key);
    auto [flo, fhi] = fresh.equal_range(key);
    std::vector<float> ms, fs;
    for (auto m = mlo; m != mhi; ++m) ms.push_back(Luminance(m->second.radiance));
    for (auto f = flo; f != fhi; ++f) fs.push_back(Luminance(f->second.radiance));
    while (!ms.empty() && !fs.empty()) {
      size_t bi = 0, bj = 0;
      for (size_t i = 0; i < ms.size(); ++i)
        for (size_t j = 0; j < fs.size(); ++j)
          if (relativeDifference(ms[i], fs[j]) < relativeDifference(ms[bi], fs[bj])) {
            bi = i;
            bj = j;
          }
      const double best = relativeDifference(ms[bi], fs[bj]);
      ++a.compared;
      a.meanRelative += best;
      if (best > 0.21) ++a.outside;
      if (best > worstRel) {
        worstRel = best;
        a.worst = fmt::format("object {} at ({:.4f}, {:.4f}, {:.4f}): relative difference {:.3f} (luminance {:.4g} "
                              "against {:.4g} fresh, floor {:.4g})",
                              key.object, double(key.position[0]) * 1e-4, double(key.position[1]) * 1e-4,
                              double(key.position[2]) * 1e-4, best, ms[bi], fs[bj], floor);
      }
      ms.erase(ms.begin() + ptrdiff_t(bi));
      fs.erase(fs.begin() + ptrdiff_t(bj));
    }
  }
  if (a.compared > 0) a.meanRelative /= double(a.compared);
  return a;
}

// A scene file equal to cornell-box-floating.json with the box placed at
// `objectToWorld` when it loads: the "fresh stack" of item 5 (b).
std::string WriteSceneWithBoxAt(const RigidTransform& objectToWorld, const std::string& tag) {
  std::ifstream in(kFloating);
  nlohmann::json doc = nlohmann::json::parse(in);
  doc["mesh"] = (fs::path(kScenesDir) / doc["mesh"].get<std::string>()).string();
  auto& box = doc["objects"]["box"];
  box["mesh"] = (fs::path(kScenesDir) / box["mesh"].get<std::string>()).string();
  const auto m = objectToWorld.ToRowMajor();
  box["transform"] = nlohmann::json{{"matrix", std::vector<float>(m.begin(), m.end())}};
  const fs::path dir = fs::temp_directory_path() / fmt::format("penumbra-moving-{}-{}", tag, ::getpid());
  fs::create_directories(dir);
  const fs::path out = dir / "scene.json";
  std::ofstream(out) << doc.dump(2);
  return out.string();
}

CameraView ViewNamed(const SmaTestClient& c, const std::string& name) {
  for (const auto& p : c.Info().cameras())
    if (p.name() == name) return ViewFromPreset(p, kWidth, kHeight);
  ADD_FAILURE() << "no camera preset " << name;
  return CameraView{};
}

// Runs a fresh stack with the box already at `boxAt`, converges the same
// view, and returns what its client holds.
std::multimap<PlaceKey, HeldSample> FreshStackSamples(const RigidTransform& boxAt, const std::string& view) {
  const std::string scene = WriteSceneWithBoxAt(boxAt, view);
  Stack fresh = StartStack(scene, 1, "fresh");
  auto client = SmaTestClient::Connect(fresh.sma.port, "fresh-client");
  EXPECT_TRUE(client.ok()) << (client.ok() ? "" : client.error().message);
  if (!client.ok()) return {};
  const wire::MovableObjectInfo* box = FindObject(client->Info(), "box");
  EXPECT_NE(box, nullptr);
  if (box) {
    const RigidTransform t = TransformOf(*box);
    EXPECT_LT(glm::length(t.translation - boxAt.translation), 1e-4f) << "the fresh scene did not place the box";
  }
  EXPECT_TRUE(client->SendView(ViewNamed(*client, view), 1));
  auto ok = client->WaitConverged(1, 120s);
  EXPECT_TRUE(ok.ok()) << (ok.ok() ? "" : ok.error().message) << fresh.sma.process.LogTail();
  return SamplesByPlace(*client);
}

class MovingObjectsTest : public ::testing::Test {};

// (a) + (b): after a move and convergence, every held sample agrees with a
// fresh stack started with the box at its new place. `smaArgs` choose how
// the move's invalidation decides; with `expectTestsKept`, some samples must
// have been kept by a renderer's test of their change (so the comparison
// covers what the test kept, not only what was shaded again).
void CheckAMovedBoxConvergesToWhatAFreshStackComputes(const std::vector<std::string>& smaArgs, bool expectTestsKept) {
  Stack stack = StartStack(kFloating, 1, "moved", smaArgs);
  auto client = SmaTestClient::Connect(stack.sma.port, "mover");
  ASSERT_TRUE(client.ok()) << client.error().message;
  const wire::MovableObjectInfo* box = FindObject(client->Info(), "box");
  ASSERT_NE(box, nullptr) << "cornell-box-floating.json has no object called box";
  EXPECT_EQ(client->Info().scene_epoch(), 0u);
  const RigidTransform start = TransformOf(*box);
  const uint32_t boxId = box->object();

  ASSERT_TRUE(client->SendView(ViewNamed(*client, "front"), 1));
  ASSERT_TRUE(client->WaitConverged(1, 120s).ok()) << stack.sma.process.LogTail();
  const auto before = SamplesByPlace(*client);

  RigidTransform target = start;
  target.translation += kMoveBy;
  const auto m = target.ToRowMajor();
  ASSERT_TRUE(client->Wire().Send(MoveEnvelope(7, boxId, m)));
  uint64_t reshaded = 0;
  auto ok = WaitMovedAndConverged(*client, 1, 1, 120s, nullptr, &reshaded);
  ASSERT_TRUE(ok.ok()) << ok.error().message << stack.sma.process.LogTail();
  EXPECT_GT(reshaded, 0u) << "no RESHADED update reached the client";
  auto epoch = client->Counter("scene_epoch");
  ASSERT_TRUE(epoch.ok()) << epoch.error().message;
  EXPECT_EQ(*epoch, 1.0);
  auto tested = client->Counter("samples_tested");
  auto kept = client->Counter("tests_kept");
  auto failed = client->Counter("tests_failed");
  ASSERT_TRUE(tested.ok() && kept.ok() && failed.ok());
  std::printf("the move's test: %.0f samples held back, %.0f kept, %.0f shaded again\n", *tested, *kept, *failed);
  // Held vertices a test kept are not re-sent: the client shows that value.
  auto keptHeld = client->Counter("client_kept_held");
  ASSERT_TRUE(keptHeld.ok()) << keptHeld.error().message;
  std::printf("held vertices kept by the test (not re-sent): %.0f; RESHADED vertex updates: %llu\n", *keptHeld,
              static_cast<unsigned long long>(reshaded));
  if (expectTestsKept) {
    EXPECT_GT(*kept, 0.0) << "no sample was kept by a test: the comparison does not cover the test";
    EXPECT_GT(*keptHeld, 0.0) << "no vertex the client holds was kept by a test";
  } else {
    EXPECT_EQ(*tested, 0.0);
    EXPECT_EQ(*keptHeld, 0.0);
  }
  const auto after = SamplesByPlace(*client);

  const auto fresh = FreshStackSamples(target, "front");
  const Agreement moved = Compare(after, fresh);
  const Agreement stale = Compare(before, fresh);
  std::printf("after the move: %zu samples compared with a fresh stack, %zu beyond 21 %%, mean %.3f, worst %s; "
              "before the move: %zu compared, %zu beyond, mean %.3f; %llu RESHADED updates\n",
              moved.compared, moved.outside, moved.meanRelative, moved.worst.c_str(), stale.compared, stale.outside,
              stale.meanRelative, static_cast<unsigned long long>(reshaded));
  EXPECT_GT(moved.compared, 100u);
  EXPECT_EQ(moved.outside, 0u) << moved.compared << " compared; worst " << moved.worst;
  EXPECT_LT(moved.meanRelative, 0.05) << "worst " << moved.worst;
  // The check can fail: the samples from before the move do not agree with
  // the fresh stack where the shadow moved.
  EXPECT_GT(stale.outside, 0u) << "the move changed nothing the comparison can see";
  ASSERT_TRUE(stack.sma.process.Running()) << stack.sma.process.LogTail();
}

// The default: the indirect class is tested, the direct class re-shaded.
TEST_F(MovingObjectsTest, AMovedBoxConvergesToWhatAFreshStackComputes) {
  CheckAMovedBoxConvergesToWhatAFreshStackComputes({}, /*expectTestsKept=*/true);
}

// The direct class tested too (--move-test-direct): samples in the box's
// shafts are kept only where their light did not change.
TEST_F(MovingObjectsTest, AMovedBoxConvergesToWhatAFreshStackComputesWithTheDirectClassTestedToo) {
  CheckAMovedBoxConvergesToWhatAFreshStackComputes({"--move-test-direct", "true"}, /*expectTestsKept=*/true);
}

// Without the test, the bound alone invalidates (--move-test-paths 0).
TEST_F(MovingObjectsTest, AMovedBoxConvergesToWhatAFreshStackComputesWithTheBoundAlone) {
  CheckAMovedBoxConvergesToWhatAFreshStackComputes({"--move-test-paths", "0"}, /*expectTestsKept=*/false);
}

// (c) Two clients of the same SMA both see the move, and hold the same
// radiance for the vertices they share.
TEST_F(MovingObjectsTest, TwoClientsBothSeeTheMove) {
  Stack stack = StartStack(kFloating, 1, "two");
  auto mover = SmaTestClient::Connect(stack.sma.port, "mover");
  auto watcher = SmaTestClient::Connect(stack.sma.port, "watcher");
  ASSERT_TRUE(mover.ok() && watcher.ok());
  const wire::MovableObjectInfo* box = FindObject(mover->Info(), "box");
  ASSERT_NE(box, nullptr);
  ASSERT_TRUE(mover->SendView(ViewNamed(*mover, "front"), 1));
  ASSERT_TRUE(watcher->SendView(ViewNamed(*watcher, "corner"), 1));
  ASSERT_TRUE(mover->WaitConverged(1, 120s).ok());
  ASSERT_TRUE(watcher->WaitConverged(1, 120s).ok());

  RigidTransform target = TransformOf(*box);
  target.translation += kMoveBy;
  ASSERT_TRUE(mover->Wire().Send(MoveEnvelope(1, box->object(), target.ToRowMajor())));
  bool watcherSawMoved = false;
  ASSERT_TRUE(WaitMovedAndConverged(*mover, 1, 1, 120s).ok());
  auto ok = WaitMovedAndConverged(*watcher, 1, 1, 120s, &watcherSawMoved);
  ASSERT_TRUE(ok.ok()) << ok.error().message;
  EXPECT_TRUE(watcherSawMoved);
  size_t shared = 0;
  for (const auto& [id, v] : mover->Mesh().Vertices()) {
    auto it = watcher->Mesh().Vertices().find(id);
    if (it == watcher->Mesh().Vertices().end()) continue;
    ++shared;
    // One cache: a vertex both hold has one sample. The watcher may lag one
    // improvement round behind, so allow the noise of one estimate.
    const float a = Luminance(v.radiance), b = Luminance(it->second.radiance);
    EXPECT_LE(std::abs(a - b), 0.1f * std::max(a, b) + 1e-3f) << "vertex " << id;
  }
  EXPECT_GT(shared, 10u);
}

// (d) A bad move is refused with a non-fatal INVALID_REQUEST and changes
// nothing: unknown object, NaN, a scale, a mirror, too few numbers, and an
// object that follows its animation.
TEST_F(MovingObjectsTest, BadMovesAreRefusedAndChangeNothing) {
  Stack stack = StartStack(kFloating, 1, "bad");
  auto client = SmaTestClient::Connect(stack.sma.port, "bad-mover");
  ASSERT_TRUE(client.ok());
  const wire::MovableObjectInfo* box = FindObject(client->Info(), "box");
  ASSERT_NE(box, nullptr);
  const auto good = TransformOf(*box).ToRowMajor();
  auto scaled = good;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) scaled[4 * r + c] *= 1.5f;
  auto mirrored = good;
  for (int r = 0; r < 3; ++r) mirrored[4 * r] = -mirrored[4 * r];
  auto withNan = good;
  withNan[3] = std::nanf("");
  struct Case {
    std::string name;
    uint32_t object;
    std::vector<float> m;
  };
  const std::vector<Case> cases = {
      {"unknown object", 99, {good.begin(), good.end()}},
      {"static part", 0, {good.begin(), good.end()}},
      {"NaN", box->object(), {withNan.begin(), withNan.end()}},
      {"scale", box->object(), {scaled.begin(), scaled.end()}},
      {"mirror", box->object(), {mirrored.begin(), mirrored.end()}},
      {"11 numbers", box->object(), {good.begin(), good.end() - 1}},
  };
  uint64_t requestId = 100;
  for (const Case& c : cases) {
    ASSERT_TRUE(client->Wire().Send(MoveEnvelope(++requestId, c.object, c.m))) << c.name;
    bool answered = false;
    for (int i = 0; i < 50 && !answered; ++i) {
      auto e = client->Wire().Receive(5s);
      ASSERT_TRUE(e.ok()) << c.name << ": " << e.error().message;
      ASSERT_FALSE(e->has_delta() && e->delta().kind() == wire::DELTA_KIND_MOVED) << c.name << " moved the box";
      if (!e->has_error()) continue;
      EXPECT_EQ(e->error().code(), wire::ERROR_CODE_INVALID_REQUEST) << c.name;
      EXPECT_EQ(e->error().request_id(), requestId) << c.name;
      EXPECT_FALSE(e->error().fatal()) << c.name;
      EXPECT_FALSE(e->error().message().empty()) << c.name;
      answered = true;
    }
    EXPECT_TRUE(answered) << c.name << ": no error reply";
  }
  auto epoch = client->Counter("scene_epoch");
  ASSERT_TRUE(epoch.ok()) << epoch.error().message;
  EXPECT_EQ(*epoch, 0.0) << "a refused move changed the scene";
  ASSERT_TRUE(stack.sma.process.Running()) << stack.sma.process.LogTail();

  // An animated object follows its path: a client may not move it.
  Stack animated = StartStack(kAnimated, 1, "animated");
  auto watcher = SmaTestClient::Connect(animated.sma.port, "animation-watcher");
  ASSERT_TRUE(watcher.ok());
  const wire::MovableObjectInfo* animatedBox = FindObject(watcher->Info(), "box");
  ASSERT_NE(animatedBox, nullptr);
  EXPECT_TRUE(animatedBox->animated());
  ASSERT_TRUE(watcher->Wire().Send(MoveEnvelope(5, animatedBox->object(), {good.begin(), good.end()})));
  bool refused = false;
  uint64_t movedDeltas = 0;
  for (int i = 0; i < 200 && !refused; ++i) {
    auto e = watcher->Wire().Receive(5s);
    ASSERT_TRUE(e.ok()) << e.error().message;
    if (e->has_delta() && e->delta().kind() == wire::DELTA_KIND_MOVED) ++movedDeltas;
    if (e->has_error() && e->error().request_id() == 5) {
      EXPECT_EQ(e->error().code(), wire::ERROR_CODE_INVALID_REQUEST);
      refused = true;
    }
  }
  EXPECT_TRUE(refused);
  // The animation itself moves the box, by the SMA's clock, with no client
  // asking: a watcher sees MOVED deltas within a second.
  const auto deadline = std::chrono::steady_clock::now() + 5s;
  while (movedDeltas < 3 && std::chrono::steady_clock::now() < deadline) {
    auto e = watcher->Wire().Receive(1s);
    if (e.ok() && e->has_delta() && e->delta().kind() == wire::DELTA_KIND_MOVED) ++movedDeltas;
  }
  EXPECT_GE(movedDeltas, 3u) << "the animation did not play";
}

// (e) A renderer killed while the samples a move invalidated are in flight:
// the other renderer shades them, and the result still matches a fresh stack.
TEST_F(MovingObjectsTest, ARendererKilledDuringAMoveLosesNoUpdate) {
  Stack stack = StartStack(kFloating, 2, "killed");
  auto client = SmaTestClient::Connect(stack.sma.port, "mover");
  ASSERT_TRUE(client.ok());
  const wire::MovableObjectInfo* box = FindObject(client->Info(), "box");
  ASSERT_NE(box, nullptr);
  ASSERT_TRUE(client->SendView(ViewNamed(*client, "front"), 1));
  ASSERT_TRUE(client->WaitConverged(1, 120s).ok());
  RigidTransform target = TransformOf(*box);
  target.translation += kMoveBy;
  ASSERT_TRUE(client->Wire().Send(MoveEnvelope(9, box->object(), target.ToRowMajor())));
  // Wait for the MOVED delta, so re-shading is under way, then kill one.
  for (int i = 0; i < 200; ++i) {
    auto e = client->Wire().Receive(5s);
    ASSERT_TRUE(e.ok()) << e.error().message;
    ASSERT_TRUE(client->Apply(*e).ok());
    if (e->has_delta() && e->delta().kind() == wire::DELTA_KIND_MOVED) break;
  }
  stack.renderers[0].process.Signal(SIGKILL);
  auto ok = WaitMovedAndConverged(*client, 1, 1, 180s, nullptr, nullptr, /*needMoved=*/false);
  ASSERT_TRUE(ok.ok()) << ok.error().message << stack.sma.process.LogTail();
  const auto fresh = FreshStackSamples(target, "front");
  const Agreement agreement = Compare(SamplesByPlace(*client), fresh);
  EXPECT_GT(agreement.compared, 100u);
  EXPECT_EQ(agreement.outside, 0u) << "worst " << agreement.worst;
  ASSERT_TRUE(stack.sma.process.Running()) << stack.sma.process.LogTail();
}

}  // namespace
}  // namespace penumbra::testing
