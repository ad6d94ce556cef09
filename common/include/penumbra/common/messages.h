#pragma once
// Envelope encoding and per-field validation of wire messages. Plain code,
// no sockets: everything here is unit-tested with bytes.

#include <cstdint>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/wire.pb.h"

namespace penumbra {

inline constexpr uint32_t kProtocolVersion = wire::PROTOCOL_VERSION_CURRENT;
/// The longest Hello.peer_name accepted (it is logged, escaped: Printable).
inline constexpr size_t kMaxPeerNameBytes = 256;

/// Serializes `envelope` into one frame (length prefix + payload).
std::string EncodeEnvelopeFrame(const wire::Envelope& envelope);

/// Parses one frame payload. Fails on undecodable bytes and on an envelope
/// with no body (which is what an empty or foreign payload decodes to).
Expected<wire::Envelope> DecodeEnvelope(std::string_view payload);

/// Name of the envelope's body ("hello", "shade_request", ...) for messages.
std::string_view BodyName(const wire::Envelope& envelope);

/// Checks a Hello against what this server speaks: the protocol version, the
/// expected peer role, and (when both are non-zero) the scene identity.
/// The Error's code is written to `code`.
Status ValidateHello(const wire::Hello& hello, wire::Role expectedRole, uint64_t sceneHash,
                     wire::ErrorCode* code);

/// Same checks for the Welcome a client receives.
Status ValidateWelcome(const wire::Welcome& welcome, wire::Role expectedRole, uint64_t sceneHash,
                       wire::ErrorCode* code);

/// The Hello every connecting side sends first (a client, the SMA to its
/// renderers, tests): `sceneHash` 0 takes whatever scene the server has;
/// an empty `authToken` presents none.
wire::Envelope MakeHello(wire::Role role, std::string_view peerName, uint64_t sceneHash,
                         std::string_view authToken = {}, uint32_t protocolVersion = kProtocolVersion);

/// Appends one named counter to a StatsReply.
void AddCounter(wire::StatsReply* reply, std::string_view name, double value);
/// A StatsReply's counters as (name, value) pairs, for metrics::WriteCounters.
std::vector<std::pair<std::string, double>> CounterPairs(const wire::StatsReply& reply);

wire::Envelope MakeError(uint64_t requestId, wire::ErrorCode code, std::string message, bool fatal);
wire::Envelope MakeHeartbeat();

}  // namespace penumbra
