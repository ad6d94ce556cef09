#include "penumbra/common/auth.h"

#include <sys/stat.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <fstream>

#include <fmt/format.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>

namespace penumbra {

Expected<AuthTokenFile> ReadAuthTokenFile(const std::filesystem::path& path) {
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0)
    return Fail(fmt::format("auth token file {}: {}", path.string(), std::strerror(errno)));
  if (!S_ISREG(info.st_mode)) return Fail(fmt::format("auth token file {}: not a regular file", path.string()));
  std::ifstream in(path, std::ios::binary);
  if (!in) return Fail(fmt::format("auth token file {}: cannot be opened for reading", path.string()));
  // One byte more than allowed tells a too-large file from a full one.
  std::string token(kMaxAuthTokenBytes + 1, '\0');
  in.read(token.data(), std::streamsize(token.size()));
  if (in.bad()) return Fail(fmt::format("auth token file {}: read error", path.string()));
  token.resize(size_t(in.gcount()));
  if (token.size() > kMaxAuthTokenBytes)
    return Fail(fmt::format("auth token file {}: larger than {} bytes (a token is one short line)", path.string(),
                            kMaxAuthTokenBytes));
  while (!token.empty() && (token.back() == '\n' || token.back() == '\r')) token.pop_back();
  if (token.empty()) return Fail(fmt::format("auth token file {}: holds no token (the file is empty)", path.string()));
  AuthTokenFile out;
  out.token = std::move(token);
  if ((info.st_mode & (S_IRWXG | S_IRWXO)) != 0)
    out.warning = fmt::format("auth token file {} is accessible to its group or to others (mode {:03o}); "
                              "chmod 600 it",
                              path.string(), unsigned(info.st_mode & 0777));
  return out;
}

namespace {
std::array<unsigned char, 32> Sha256(std::string_view text) {
  std::array<unsigned char, 32> digest{};
  unsigned int length = 0;
  EVP_Digest(text.data(), text.size(), digest.data(), &length, EVP_sha256(), nullptr);
  return digest;
}
}  // namespace

bool AuthTokenMatches(std::string_view presented, std::string_view expected) {
  // Hashing first makes the comparison independent of the lengths too.
  const auto a = Sha256(presented);
  const auto b = Sha256(expected);
  return CRYPTO_memcmp(a.data(), b.data(), a.size()) == 0;
}

Status CheckHelloToken(const wire::Hello& hello, std::string_view expected, wire::ErrorCode* code) {
  if (expected.empty()) return Status::Ok();
  if (hello.auth_token().empty()) {
    if (code) *code = wire::ERROR_CODE_AUTH_FAILED;
    return Fail("authentication failed: this server requires a token and the hello carries none "
                "(give the connecting side --auth-token-file)");
  }
  if (!AuthTokenMatches(hello.auth_token(), expected)) {
    if (code) *code = wire::ERROR_CODE_AUTH_FAILED;
    return Fail("authentication failed: the hello's token is not this server's");
  }
  return Status::Ok();
}

}  // namespace penumbra
