#include "penumbra/common/tls.h"

#include <system_error>

#include <fmt/format.h>
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>
#include <openssl/x509err.h>

namespace penumbra::net {

namespace {
using boost::system::error_code;

Status CheckReadable(const std::filesystem::path& file, const char* what) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec))
    return Fail(fmt::format("{} {}: {}", what, file.string(), ec ? ec.message() : std::string("not a regular file")));
  return Status::Ok();
}

std::string SslMessage(const error_code& ec) {
  // OpenSSL's reason ("PEM lib", "key values mismatch") names the problem.
  return ec.category() == asio::error::get_ssl_category() ? fmt::format("{} (OpenSSL)", ec.message()) : ec.message();
}

void RestrictVersions(ssl::context& context) {
  // TLS 1.0/1.1 are deprecated (RFC 8996).
  SSL_CTX_set_min_proto_version(context.native_handle(), TLS1_2_VERSION);
  context.set_options(ssl::context::default_workarounds | ssl::context::no_sslv2 | ssl::context::no_sslv3 |
                      ssl::context::no_compression);
}
}  // namespace

Expected<std::shared_ptr<ssl::context>> MakeTlsServerContext(const std::filesystem::path& certChainFile,
                                                             const std::filesystem::path& keyFile) {
  if (auto ok = CheckReadable(certChainFile, "--tls-cert"); !ok) return ok.error();
  if (auto ok = CheckReadable(keyFile, "--tls-key"); !ok) return ok.error();
  auto context = std::make_shared<ssl::context>(ssl::context::tls_server);
  RestrictVersions(*context);
  error_code ec;
  context->use_certificate_chain_file(certChainFile.string(), ec);
  if (ec) return Fail(fmt::format("--tls-cert {}: not a PEM certificate chain: {}", certChainFile.string(), SslMessage(ec)));
  context->use_private_key_file(keyFile.string(), ssl::context::pem, ec);
  if (ec && ec.category() == asio::error::get_ssl_category() &&
      ERR_GET_REASON(static_cast<unsigned long>(ec.value())) == X509_R_KEY_VALUES_MISMATCH)
    return Fail(fmt::format("--tls-key {} is not the key of the certificate in --tls-cert {}", keyFile.string(),
                            certChainFile.string()));
  if (ec) return Fail(fmt::format("--tls-key {}: not an unencrypted PEM private key: {}", keyFile.string(), SslMessage(ec)));
  if (SSL_CTX_check_private_key(context->native_handle()) != 1) {
    ERR_clear_error();
    return Fail(fmt::format("--tls-key {} is not the key of the certificate in --tls-cert {}", keyFile.string(),
                            certChainFile.string()));
  }
  return context;
}

Expected<std::shared_ptr<ssl::context>> MakeTlsClientContext(const std::filesystem::path& caFile) {
  if (auto ok = CheckReadable(caFile, "TLS CA file"); !ok) return ok.error();
  auto context = std::make_shared<ssl::context>(ssl::context::tls_client);
  RestrictVersions(*context);
  error_code ec;
  context->load_verify_file(caFile.string(), ec);
  if (ec) return Fail(fmt::format("TLS CA file {}: no PEM CA certificate in it: {}", caFile.string(), SslMessage(ec)));
  context->set_verify_mode(ssl::verify_peer, ec);
  if (ec) return Fail(fmt::format("TLS CA file {}: {}", caFile.string(), SslMessage(ec)));
  return context;
}

std::string DescribeTlsFailure(const error_code& ec, TlsStream& stream) {
  std::string text = SslMessage(ec);
  const long verify = SSL_get_verify_result(stream.native_handle());
  if (verify != X509_V_OK)
    text += fmt::format("; the peer's certificate was refused: {}", X509_verify_cert_error_string(verify));
  return text;
}

bool LooksLikeTlsClientHello(const unsigned char* bytes, size_t size) {
  return size >= 3 && bytes[0] == 0x16 && bytes[1] == 0x03 && bytes[2] >= 0x01 && bytes[2] <= 0x04;
}

}  // namespace penumbra::net
