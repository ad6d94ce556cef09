#pragma once
// Shared-secret authentication of peers (docs/deploy.md, "Tokens and TLS").
// A server started with --auth-token-file requires Hello.auth_token to equal
// the file's token; a connecting side started with --auth-token-file sends
// it. The token is never logged and never appears in an error message.
//
// Threads: plain functions, callable from any thread.

#include <cstddef>
#include <filesystem>
#include <string>
#include <string_view>

#include "penumbra/common/expected.h"
#include "penumbra/wire.pb.h"

namespace penumbra {

/// The largest token file read (a token is a short random string; anything
/// larger is a wrong file, and a Hello must stay far below the 64 KiB a
/// server accepts before the handshake).
inline constexpr size_t kMaxAuthTokenBytes = 1024;

struct AuthTokenFile {
  std::string token;
  /// Non-empty when the file is readable by its group or by others: a
  /// start-up warning for the operator (the file is still used).
  std::string warning;
};

/// Reads a token file: at most kMaxAuthTokenBytes, trailing newlines (\n,
/// \r\n) stripped. Fails with a message naming the file (never quoting it)
/// when it cannot be read, is too large, or holds an empty token.
Expected<AuthTokenFile> ReadAuthTokenFile(const std::filesystem::path& path);

/// True when `presented` equals `expected`, in time independent of where
/// they differ (both are hashed, the digests compared with CRYPTO_memcmp),
/// so that a peer cannot learn the token byte by byte from response times.
bool AuthTokenMatches(std::string_view presented, std::string_view expected);

/// A server's check of a Hello: accepts everything when `expected` is empty
/// (no token configured); otherwise fails with code AUTH_FAILED unless the
/// Hello carries exactly `expected`.
Status CheckHelloToken(const wire::Hello& hello, std::string_view expected, wire::ErrorCode* code);

}  // namespace penumbra
