// Records the fuzz targets' seed corpora (tests/fuzz/corpus/) from real
// traffic: a renderer and an SMA on the shipped Cornell box, with this tool
// relaying every frame between them (it listens as the SMA's renderer and
// connects to the real one) and playing a client of the SMA (Hello,
// SessionOptions, a View of the front camera, a StatsRequest and a
// TextureRequest) until the view converges. Every frame that crosses is
// kept; the seeds are the first frames of each kind, with shade requests and
// replies cut to their first few samples, so that each corpus stays a few KB.
//
// Usage: record_fuzz_seeds <corpus folder>   (normally tests/fuzz/corpus)
// Built with the tests (build/tests/record_fuzz_seeds); not itself a test.

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <google/protobuf/reflection.h>

#include "penumbra/common/framing.h"
#include "penumbra/common/messages.h"
#include "support/service.h"
#include "support/wire_client.h"

namespace fs = std::filesystem;
using namespace penumbra;
using namespace penumbra::testing;
using namespace std::chrono_literals;

namespace {

// What crossed, in order, per direction.
struct Traffic {
  std::mutex mutex;
  std::vector<wire::Envelope> toRenderer;   // from the SMA
  std::vector<wire::Envelope> fromRenderer;  // to the SMA
};

// Keeps the first `keep` samples of a ShadeRequest or ShadeReply: every
// repeated field holds the same number of values per sample.
void KeepSamples(google::protobuf::Message& message, int keep) {
  const auto* descriptor = message.GetDescriptor();
  const auto* reflection = message.GetReflection();
  const int n = reflection->FieldSize(message, descriptor->FindFieldByName("sample_ids"));
  if (n <= keep) return;
  for (int f = 0; f < descriptor->field_count(); ++f) {
    const auto* field = descriptor->field(f);
    if (!field->is_repeated()) continue;
    const int size = reflection->FieldSize(message, field);
    const int per = size / n;
    while (reflection->FieldSize(message, field) > per * keep) reflection->RemoveLast(&message, field);
  }
}

void Write(const fs::path& path, const std::string& bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << bytes;
  std::cout << path.string() << ": " << bytes.size() << " bytes\n";
}

std::string Payload(const wire::Envelope& e) { return e.SerializeAsString(); }
std::string Frame(const wire::Envelope& e) { return EncodeFrame(Payload(e)); }

int Quit(const std::string& message) {
  std::cerr << "record_fuzz_seeds: " << message << "\n";
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) return Quit("usage: record_fuzz_seeds <corpus folder>");
  const fs::path out = argv[1];
  const std::string scene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/cornell-box.json";

  auto renderer = StartService(PENUMBRA_RENDERER_EXE, {"--scene", scene, "--threads", "2"}, "seed-renderer");
  if (!renderer) return Quit(renderer.error().message);
  auto relay = WireListener::Listen();
  if (!relay) return Quit(relay.error().message);
  auto sma = StartService(PENUMBRA_SMA_EXE,
                          {"--scene", scene, "--renderer", "127.0.0.1:" + std::to_string(relay->Port())}, "seed-sma");
  if (!sma) return Quit(sma.error().message);

  auto smaSide = relay->Accept(30s);
  if (!smaSide) return Quit("the SMA did not connect: " + smaSide.error().message);
  auto rendererSide = WireClient::Connect("127.0.0.1", renderer->port);
  if (!rendererSide) return Quit(rendererSide.error().message);

  Traffic traffic;
  std::atomic<bool> stop{false};
  std::thread pump([&] {
    while (!stop) {
      if (auto e = smaSide->Receive(2ms, false)) {
        rendererSide->Send(*e);
        std::lock_guard lock(traffic.mutex);
        traffic.toRenderer.push_back(*e);
      }
      if (auto e = rendererSide->Receive(2ms, false)) {
        smaSide->Send(*e);
        std::lock_guard lock(traffic.mutex);
        traffic.fromRenderer.push_back(*e);
      }
    }
  });

  // The client: every frame it sends and receives.
  std::vector<wire::Envelope> sent, received;
  auto client = WireClient::Connect("127.0.0.1", sma->port);
  if (!client) return Quit(client.error().message);
  auto send = [&](const wire::Envelope& e) {
    sent.push_back(e);
    client->Send(e);
  };
  send(MakeHello(wire::ROLE_CLIENT, "seed-recorder", 0));
  wire::Envelope options;
  options.mutable_session_options()->set_criterion("nld_os");
  options.mutable_session_options()->set_s_req(0.04f);
  options.mutable_session_options()->set_noise_z(2.0f);
  wire::Envelope view;
  auto* v = view.mutable_view();
  v->set_view_id(1);
  auto set = [](wire::Vec3* w, float x, float y, float z) {
    w->set_x(x);
    w->set_y(y);
    w->set_z(z);
  };
  set(v->mutable_eye(), 0.0f, 1.0f, 3.9f);  // the scene file's "front" camera
  set(v->mutable_target(), 0.0f, 1.0f, 0.0f);
  set(v->mutable_up(), 0.0f, 1.0f, 0.0f);
  v->set_fov_y_deg(40.0f);
  v->set_width(160);
  v->set_height(120);
  wire::Envelope stats;
  stats.mutable_stats_request()->set_request_id(7);
  wire::Envelope texture;
  texture.mutable_texture_request()->set_texture(0);

  bool converged = false;
  const auto deadline = std::chrono::steady_clock::now() + 120s;
  while (!converged && std::chrono::steady_clock::now() < deadline) {
    auto e = client->Receive(1s);
    if (!e) {
      if (e.error().message == "timeout") continue;
      return Quit("the SMA closed: " + e.error().message);
    }
    received.push_back(*e);
    if (e->has_scene_info()) {
      send(options);
      send(view);
      send(stats);
      send(texture);
    }
    if (e->has_delta() && e->delta().view_id() == 1 && e->delta().converged()) converged = true;
  }
  stop = true;
  pump.join();
  if (!converged) return Quit("the view did not converge in 120 s");

  // --- Seeds -------------------------------------------------------------------
  constexpr size_t kBudget = 4096;  // bytes per seed file, about
  // A stream of frames, cut at a frame boundary near the budget.
  auto stream = [&](const std::vector<wire::Envelope>& envelopes, size_t budget, bool (*want)(const wire::Envelope&)) {
    std::string bytes;
    for (const auto& e : envelopes) {
      if (!want(e)) continue;
      std::string f = Frame(e);
      if (!bytes.empty() && bytes.size() + f.size() > budget) break;
      bytes += f;
    }
    return bytes;
  };
  auto any = [](const wire::Envelope&) { return true; };
  auto deltas = [](const wire::Envelope& e) { return e.has_delta(); };

  // Framing: the client's received stream, cut into reads of 1, 7 and 256 bytes.
  {
    const std::string s = stream(received, kBudget, any);
    for (unsigned char chunk : {0, 6, 255}) Write(out / "fuzz_framing" / ("client-stream-chunk" + std::to_string(chunk + 1)), std::string(1, char(chunk)) + s);
    Write(out / "fuzz_framing" / "client-sent-chunk64", std::string(1, char(63)) + stream(sent, kBudget, any));
  }
  // Client: Welcome, SceneInfo and deltas as received.
  Write(out / "fuzz_client_session" / "cornell-front", stream(received, 2 * kBudget, any));
  // Mesh store: the deltas alone, in order.
  Write(out / "fuzz_mesh_store" / "cornell-front-deltas", stream(received, 2 * kBudget, deltas));
  // SMA, from a client: each message the client sent.
  for (const auto& e : sent) Write(out / "fuzz_sma_client_message" / std::string(BodyName(e)), Payload(e));

  std::lock_guard lock(traffic.mutex);
  // Renderer, from the SMA: its Hello and the first requests of each kind.
  int requests = 0, replies = 0;
  for (auto e : traffic.toRenderer) {
    if (e.has_hello()) Write(out / "fuzz_renderer_message" / "hello", Payload(e));
    if (e.has_shade_request() && requests < 4) {
      KeepSamples(*e.mutable_shade_request(), 12);
      Write(out / "fuzz_renderer_message" / ("shade-request-" + std::to_string(requests++)), Payload(e));
    }
  }
  // SMA, from the renderer: its Welcome and the reply parts with the most
  // samples (most parts carry one or two), the last parts of batches first.
  std::stable_sort(traffic.fromRenderer.begin(), traffic.fromRenderer.end(), [](const auto& a, const auto& b) {
    return a.shade_reply().sample_ids_size() > b.shade_reply().sample_ids_size();
  });
  for (auto e : traffic.fromRenderer) {
    if (e.has_welcome()) Write(out / "fuzz_sma_shade_reply" / "welcome", Payload(e));
    if (e.has_shade_reply() && replies < 4) {
      KeepSamples(*e.mutable_shade_reply(), 12);
      Write(out / "fuzz_sma_shade_reply" / ("shade-reply-" + std::to_string(replies++)), Payload(e));
    }
  }
  std::cout << "recorded " << sent.size() << " client frames sent, " << received.size() << " received, "
            << traffic.toRenderer.size() << " to the renderer, " << traffic.fromRenderer.size() << " from it\n";
  return 0;
}
