#pragma once
// TLS for every Penumbra hop (docs/deploy.md, "Tokens and TLS"): OpenSSL
// through Boost.Asio's ssl::stream. A listening side holds a certificate
// chain and its key (--tls-cert, --tls-key); a connecting side holds the CA
// it trusts (--tls-ca) and verifies the server's chain and that the
// certificate names the host it connected to (asio::ssl::host_name_verification:
// a DNS name against the certificate's DNS names, an IP address against its
// IP addresses). TLS 1.2 is the oldest version spoken.
//
// `Stream` is what a net::Connection reads and writes: a plain TCP socket or
// a TLS stream whose handshake is done. Connections are plain TCP unless TLS
// flags are given.

#include <cstddef>
#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <variant>

#include "penumbra/common/asio.h"
#include "penumbra/common/check.h"
#include "penumbra/common/expected.h"

#include <boost/asio/ssl.hpp>

namespace penumbra::net {

namespace ssl = boost::asio::ssl;
using TlsStream = ssl::stream<tcp::socket>;

/// A plain socket or a TLS stream over one, handshake completed. Move-only.
/// The async calls follow Asio's rules for one stream: at most one read and
/// one write outstanding, issued (and completing) on one strand.
class Stream {
 public:
  explicit Stream(tcp::socket socket) : stream_(std::move(socket)) {}
  explicit Stream(std::unique_ptr<TlsStream> tls) : stream_(std::move(tls)) {}

  bool IsTls() const { return stream_.index() == 1; }
  /// The plain socket, moved out, for a listener that serves something else
  /// than Penumbra frames (the operator HTTP endpoint never sets TLS).
  tcp::socket TakePlainSocket() && {
    PENUMBRA_CHECK(!IsTls(), "TakePlainSocket on a TLS stream");
    return std::move(std::get<0>(stream_));
  }
  /// The TCP socket underneath (options, shutdown, close, addresses).
  tcp::socket& Socket() {
    if (auto* tls = std::get_if<1>(&stream_)) return (*tls)->next_layer();
    return std::get<0>(stream_);
  }
  const tcp::socket& Socket() const {
    if (auto* tls = std::get_if<1>(&stream_)) return (*tls)->next_layer();
    return std::get<0>(stream_);
  }

  template <class MutableBuffers, class Handler>
  void AsyncReadSome(const MutableBuffers& buffers, Handler&& handler) {
    if (auto* tls = std::get_if<1>(&stream_))
      (*tls)->async_read_some(buffers, std::forward<Handler>(handler));
    else
      std::get<0>(stream_).async_read_some(buffers, std::forward<Handler>(handler));
  }

  /// Writes all of `buffers` (asio::async_write).
  template <class ConstBuffers, class Handler>
  void AsyncWrite(const ConstBuffers& buffers, Handler&& handler) {
    if (auto* tls = std::get_if<1>(&stream_))
      asio::async_write(**tls, buffers, std::forward<Handler>(handler));
    else
      asio::async_write(std::get<0>(stream_), buffers, std::forward<Handler>(handler));
  }

  /// Synchronous writes and reads, for a stream about to be closed
  /// (RefuseConnection): on a non-blocking socket what cannot be done now
  /// fails with would_block instead of waiting.
  template <class ConstBuffers>
  size_t WriteNow(const ConstBuffers& buffers, boost::system::error_code& ec) {
    if (auto* tls = std::get_if<1>(&stream_)) return asio::write(**tls, buffers, ec);
    return asio::write(std::get<0>(stream_), buffers, ec);
  }
  template <class MutableBuffers>
  size_t ReadSomeNow(const MutableBuffers& buffers, boost::system::error_code& ec) {
    if (auto* tls = std::get_if<1>(&stream_)) return (*tls)->read_some(buffers, ec);
    return std::get<0>(stream_).read_some(buffers, ec);
  }

 private:
  std::variant<tcp::socket, std::unique_ptr<TlsStream>> stream_;
};

/// A listening side's TLS context: the certificate chain (PEM, leaf first)
/// and its private key (PEM, unencrypted). Fails with a message naming the
/// file when either cannot be loaded or the key does not match. Start-up.
Expected<std::shared_ptr<ssl::context>> MakeTlsServerContext(const std::filesystem::path& certChainFile,
                                                             const std::filesystem::path& keyFile);

/// A connecting side's TLS context: verifies peers against the CA
/// certificates in `caFile` (PEM). Start-up.
Expected<std::shared_ptr<ssl::context>> MakeTlsClientContext(const std::filesystem::path& caFile);

/// What a connecting side needs for TLS to one server: its context and the
/// name it connected to (checked against the certificate, sent as SNI).
struct TlsClientTarget {
  std::shared_ptr<ssl::context> context;
  std::string hostName;
};

/// Why a TLS handshake failed, for a human: OpenSSL's reason plus, when the
/// peer's certificate was refused, the verification result ("unable to get
/// local issuer certificate", "hostname mismatch", ...).
std::string DescribeTlsFailure(const boost::system::error_code& ec, TlsStream& stream);

/// True when `bytes` (at least 3) begin a TLS record carrying a handshake,
/// i.e. a TLS ClientHello: type 22, version major 3, and a version minor
/// that a Penumbra frame below 64 KiB cannot have in its third byte
/// (a length prefix's third byte is 0 there).
bool LooksLikeTlsClientHello(const unsigned char* bytes, size_t size);

}  // namespace penumbra::net
