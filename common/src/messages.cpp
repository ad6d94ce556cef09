#include "penumbra/common/messages.h"

#include <chrono>

#include <fmt/format.h>

#include "penumbra/common/framing.h"

namespace penumbra {

std::string EncodeEnvelopeFrame(const wire::Envelope& envelope) {
  const size_t size = envelope.ByteSizeLong();
  std::string out;
  out.resize(kFrameHeaderBytes + size);
  const auto n = uint32_t(size);
  out[0] = char(n & 0xff);
  out[1] = char((n >> 8) & 0xff);
  out[2] = char((n >> 16) & 0xff);
  out[3] = char((n >> 24) & 0xff);
  envelope.SerializeWithCachedSizesToArray(reinterpret_cast<uint8_t*>(out.data() + kFrameHeaderBytes));
  return out;
}

Expected<wire::Envelope> DecodeEnvelope(std::string_view payload) {
  wire::Envelope envelope;
  if (!envelope.ParseFromArray(payload.data(), int(payload.size())))
    return Fail(fmt::format("undecodable frame of {} bytes (not a penumbra.wire.Envelope)", payload.size()));
  if (envelope.body_case() == wire::Envelope::BODY_NOT_SET)
    return Fail(fmt::format("frame of {} bytes carries no known message", payload.size()));
  return envelope;
}

std::string_view BodyName(const wire::Envelope& envelope) {
  if (envelope.body_case() == wire::Envelope::BODY_NOT_SET) return "nothing";
  const auto* field = wire::Envelope::descriptor()->FindFieldByNumber(int(envelope.body_case()));
  return field ? std::string_view(field->name()) : std::string_view("unknown");
}

namespace {

std::string_view RoleName(wire::Role role) {
  switch (role) {
    case wire::ROLE_RENDERER: return "renderer";
    case wire::ROLE_SMA: return "sma";
    case wire::ROLE_CLIENT: return "client";
    default: return "unspecified";
  }
}

Status CheckPeer(uint32_t version, wire::Role role, uint64_t hash, wire::Role expectedRole,
                 uint64_t sceneHash, wire::ErrorCode* code) {
  if (version != kProtocolVersion) {
    *code = wire::ERROR_CODE_VERSION_MISMATCH;
    return Fail(fmt::format("protocol version {} is not supported (this peer speaks {})", version,
                            kProtocolVersion));
  }
  if (role != expectedRole) {
    *code = wire::ERROR_CODE_UNEXPECTED_MESSAGE;
    return Fail(fmt::format("peer role is {}, expected {}", RoleName(role), RoleName(expectedRole)));
  }
  if (hash != 0 && sceneHash != 0 && hash != sceneHash) {
    *code = wire::ERROR_CODE_SCENE_MISMATCH;
    return Fail(fmt::format("scene identity {:016x} differs from this peer's {:016x}: the two loaded different scenes",
                            hash, sceneHash));
  }
  return Status::Ok();
}

}  // namespace

Status ValidateHello(const wire::Hello& hello, wire::Role expectedRole, uint64_t sceneHash,
                     wire::ErrorCode* code) {
  if (hello.peer_name().size() > kMaxPeerNameBytes) {
    if (code) *code = wire::ERROR_CODE_INVALID_REQUEST;
    return Fail(fmt::format("peer_name has {} bytes; at most {} are allowed", hello.peer_name().size(),
                            kMaxPeerNameBytes));
  }
  return CheckPeer(hello.protocol_version(), hello.role(), hello.scene_hash(), expectedRole, sceneHash, code);
}

Status ValidateWelcome(const wire::Welcome& welcome, wire::Role expectedRole, uint64_t sceneHash,
                       wire::ErrorCode* code) {
  return CheckPeer(welcome.protocol_version(), welcome.role(), welcome.scene_hash(), expectedRole,
                   sceneHash, code);
}

wire::Envelope MakeHello(wire::Role role, std::string_view peerName, uint64_t sceneHash, std::string_view authToken,
                         uint32_t protocolVersion) {
  wire::Envelope envelope;
  auto* hello = envelope.mutable_hello();
  hello->set_protocol_version(protocolVersion);
  hello->set_role(role);
  hello->set_peer_name(std::string(peerName));
  hello->set_scene_hash(sceneHash);
  hello->set_auth_token(std::string(authToken));
  return envelope;
}

void AddCounter(wire::StatsReply* reply, std::string_view name, double value) {
  auto* counter = reply->add_counters();
  counter->set_name(std::string(name));
  counter->set_value(value);
}

std::vector<std::pair<std::string, double>> CounterPairs(const wire::StatsReply& reply) {
  std::vector<std::pair<std::string, double>> out;
  out.reserve(size_t(reply.counters_size()));
  for (const auto& c : reply.counters()) out.emplace_back(c.name(), c.value());
  return out;
}

wire::Envelope MakeError(uint64_t requestId, wire::ErrorCode code, std::string message, bool fatal) {
  wire::Envelope envelope;
  auto* error = envelope.mutable_error();
  error->set_request_id(requestId);
  error->set_code(code);
  error->set_message(std::move(message));
  error->set_fatal(fatal);
  return envelope;
}

wire::Envelope MakeHeartbeat() {
  wire::Envelope envelope;
  envelope.mutable_heartbeat()->set_sent_unix_ms(uint64_t(
      std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
          .count()));
  return envelope;
}

}  // namespace penumbra
