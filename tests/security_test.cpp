// Tokens and TLS on both hops (client -> SMA, SMA -> renderer), on real
// processes: a server with --auth-token-file refuses a Hello without the
// token or with another one (one fatal AUTH_FAILED, then closed) and serves
// the right one, and never logs either; TLS with the right CA serves (the
// headless client renders the Cornell box through TLS on both hops), with a
// CA that did not issue the server's certificate -- or a certificate for
// another name -- it is refused; plain and TLS peers that meet get a clear
// error. Keys and certificates are made at test time with the openssl CLI in
// a temporary folder (no private key is committed).

#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <thread>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "penumbra/common/image_io.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/scene.h"
#include "support/process.h"
#include "support/service.h"
#include "support/wire_client.h"

namespace penumbra::testing {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

const std::string kScene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/cornell-box.json";
const std::string kRendererToken = "renderer-secret-7f3a9c";
const std::string kClientToken = "client-secret-51be0d";
const std::string kWrongToken = "not-the-secret-000000";

std::string ReadWhole(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

bool Contains(const std::string& text, const std::string& what) { return text.find(what) != std::string::npos; }

bool WaitUntil(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  while (Clock::now() < deadline) {
    if (done()) return true;
    std::this_thread::sleep_for(50ms);
  }
  return done();
}

// Waits until the process's log holds `what`.
bool WaitForLog(const ChildProcess& process, const std::string& what, std::chrono::milliseconds timeout = 20s) {
  return WaitUntil([&] { return Contains(ReadWhole(process.LogPath()), what); }, timeout);
}

wire::Envelope Hello(wire::Role role, uint64_t sceneHash, const std::string& token) {
  return MakeHello(role, "security-test", sceneHash, token);
}

// Sends a Hello with `token` and returns what the server answered first.
Expected<wire::Envelope> HelloAnswer(uint16_t port, wire::Role role, uint64_t sceneHash, const std::string& token,
                                     bool* closedAfter) {
  auto client = WireClient::Connect("127.0.0.1", port);
  if (!client) return client.error();
  if (!client->Send(Hello(role, sceneHash, token))) return Fail("cannot send the hello");
  auto answer = client->Receive(10s);
  if (closedAfter) *closedAfter = answer && answer->has_error() && client->WaitClosed(5s);
  return answer;
}

// A CA, a server certificate it issued for 127.0.0.1 and localhost, another
// CA that issued nothing here, and a certificate from the first CA for
// another host name only.
struct Pki {
  std::string ca, otherCa, cert, key, wrongNameCert, wrongNameKey;
};

Expected<Pki> MakePki(const std::string& dir) {
  const auto openssl = FindExecutable("openssl");
  if (!openssl) return Fail("the openssl command is missing (scripts/install-deps.sh installs it)");
  const auto run = [&](const std::vector<std::string>& args) { return RunCommand(*openssl, args, 60s); };
  const std::vector<std::string> ec = {"-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"};
  auto selfSigned = [&](const std::string& name, const std::string& cn) -> Status {
    std::vector<std::string> args = {"req", "-x509"};
    args.insert(args.end(), ec.begin(), ec.end());
    args.insert(args.end(), {"-keyout", dir + "/" + name + ".key", "-out", dir + "/" + name + ".pem", "-days", "2",
                             "-subj", "/CN=" + cn});
    if (auto out = run(args); !out) return out.error();
    return Status::Ok();
  };
  auto issued = [&](const std::string& name, const std::string& altNames) -> Status {
    std::vector<std::string> args = {"req"};
    args.insert(args.end(), ec.begin(), ec.end());
    args.insert(args.end(), {"-keyout", dir + "/" + name + ".key", "-out", dir + "/" + name + ".csr", "-subj",
                             "/CN=penumbra-test-server"});
    if (auto out = run(args); !out) return out.error();
    std::ofstream(dir + "/" + name + ".ext") << "subjectAltName=" << altNames << "\nbasicConstraints=CA:FALSE\n";
    if (auto out = run({"x509", "-req", "-in", dir + "/" + name + ".csr", "-CA", dir + "/ca.pem", "-CAkey",
                        dir + "/ca.key", "-set_serial", std::to_string(name.size() + 1000), "-days", "2", "-out",
                        dir + "/" + name + ".pem", "-extfile", dir + "/" + name + ".ext"});
        !out)
      return out.error();
    ::chmod((dir + "/" + name + ".key").c_str(), 0600);
    return Status::Ok();
  };
  if (auto ok = selfSigned("ca", "penumbra-test-ca"); !ok) return ok.error();
  if (auto ok = selfSigned("other-ca", "penumbra-other-ca"); !ok) return ok.error();
  if (auto ok = issued("server", "IP:127.0.0.1,DNS:localhost"); !ok) return ok.error();
  if (auto ok = issued("elsewhere", "DNS:elsewhere.example"); !ok) return ok.error();
  return Pki{dir + "/ca.pem", dir + "/other-ca.pem", dir + "/server.pem", dir + "/server.key",
             dir + "/elsewhere.pem", dir + "/elsewhere.key"};
}

std::string WriteToken(const std::string& dir, const std::string& name, const std::string& token) {
  const std::string path = dir + "/" + name;
  std::ofstream(path) << token << "\n";
  ::chmod(path.c_str(), 0600);
  return path;
}

class SecurityTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    auto scene = LoadScene(kScene);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    sceneHash_ = scene->identity;
    dir_ = new std::string(MakeTempDir("penumbra-security-test"));
    auto pki = MakePki(*dir_);
    ASSERT_TRUE(pki.ok()) << pki.error().message;
    pki_ = new Pki(std::move(*pki));
    rendererTokenFile_ = new std::string(WriteToken(*dir_, "renderer.token", kRendererToken));
    clientTokenFile_ = new std::string(WriteToken(*dir_, "client.token", kClientToken));
    wrongTokenFile_ = new std::string(WriteToken(*dir_, "wrong.token", kWrongToken));
  }
  static void TearDownTestSuite() {
    // The logs stay for a look after a failure; the test keys go.
    if (pki_)
      for (const std::string& key : {pki_->key, pki_->wrongNameKey, *dir_ + "/ca.key", *dir_ + "/other-ca.key"})
        std::filesystem::remove(key);
    delete pki_;
    delete rendererTokenFile_;
    delete clientTokenFile_;
    delete wrongTokenFile_;
    delete dir_;
  }

  static Service StartRenderer(const std::vector<std::string>& extra, const std::string& tag) {
    std::vector<std::string> args = {"--scene", kScene, "--threads", "2", "--spp", "8", "--max-bounces", "2"};
    args.insert(args.end(), extra.begin(), extra.end());
    auto service = StartService(PENUMBRA_RENDERER_EXE, args, "renderer-" + tag);
    EXPECT_TRUE(service.ok()) << service.error().message;
    return service ? std::move(*service) : Service{};
  }
  static Service StartSma(const std::string& renderer, const std::vector<std::string>& extra, const std::string& tag) {
    // No refinement, no improvement: the client converges on the first image.
    std::vector<std::string> args = {"--scene", kScene, "--renderer", renderer, "--criterion", "none",
                                     "--improve-paths", "0"};
    args.insert(args.end(), extra.begin(), extra.end());
    auto service = StartService(PENUMBRA_SMA_EXE, args, "sma-" + tag);
    EXPECT_TRUE(service.ok()) << service.error().message;
    return service ? std::move(*service) : Service{};
  }
  // A headless client rendering the front view of the Cornell box until
  // converged; returns its exit code (nullopt: still running at `timeout`).
  static std::optional<int> RunClient(const std::string& address, const std::vector<std::string>& extra,
                                      const std::string& tag, std::string* log,
                                      std::chrono::milliseconds timeout = 120s) {
    const std::string exr = *dir_ + "/" + tag + ".exr";
    std::vector<std::string> args = {"--connect", address, "--headless", "--gl", "egl", "--camera", "front",
                                     "--size", "64x48", "--until-converged", "--screenshot", exr};
    args.insert(args.end(), extra.begin(), extra.end());
    auto client = ChildProcess::Spawn(PENUMBRA_CLIENT_EXE, args, *dir_ + "/client-" + tag + ".log");
    EXPECT_TRUE(client.ok()) << client.error().message;
    if (!client) return std::nullopt;
    const auto code = client->WaitExit(timeout);
    *log = ReadWhole(client->LogPath());
    return code;
  }
  // The image a converged client wrote shows something lit.
  static void ExpectLitImage(const std::string& tag) {
    auto image = ReadImage(*dir_ + "/" + tag + ".exr");
    ASSERT_TRUE(image.ok()) << image.error().message;
    ASSERT_EQ(image->width, 64);
    double sum = 0.0;
    for (float v : image->rgb) sum += v;
    EXPECT_GT(sum, 0.0) << "a converged Cornell box is not black";
  }
  static double Counter(const Service& sma, const std::string& name, const std::string& token = "") {
    auto c = WireClient::Connect("127.0.0.1", sma.port);
    if (!c) return -1;
    if (!c->Send(Hello(wire::ROLE_CLIENT, 0, token))) return -1;
    auto welcome = c->Receive(10s);
    if (!welcome || !welcome->has_welcome()) return -1;
    auto value = c->Counter(name);
    return value ? *value : -1;
  }

  static uint64_t sceneHash_;
  static std::string* dir_;
  static Pki* pki_;
  static std::string* rendererTokenFile_;
  static std::string* clientTokenFile_;
  static std::string* wrongTokenFile_;
};
uint64_t SecurityTest::sceneHash_ = 0;
std::string* SecurityTest::dir_ = nullptr;
Pki* SecurityTest::pki_ = nullptr;
std::string* SecurityTest::rendererTokenFile_ = nullptr;
std::string* SecurityTest::clientTokenFile_ = nullptr;
std::string* SecurityTest::wrongTokenFile_ = nullptr;

// Each server's hop at the protocol level: no token and a wrong token get one
// fatal AUTH_FAILED and the connection closed; the right token is welcomed;
// neither token reaches the log.
TEST_F(SecurityTest, ServersRefuseAMissingOrWrongTokenAndWelcomeTheRightOne) {
  Service renderer = StartRenderer({"--auth-token-file", *rendererTokenFile_}, "token");
  Service sma = StartSma(renderer.Address(), {"--auth-token-file", *clientTokenFile_, "--renderer-auth-token-file",
                                              *rendererTokenFile_},
                         "token");
  struct Hop {
    const Service& server;
    wire::Role role;
    uint64_t hash;
    std::string token;
  };
  for (const Hop& hop : {Hop{renderer, wire::ROLE_SMA, sceneHash_, kRendererToken},
                         Hop{sma, wire::ROLE_CLIENT, 0, kClientToken}}) {
    SCOPED_TRACE(hop.role == wire::ROLE_SMA ? "SMA -> renderer" : "client -> SMA");
    for (const std::string& bad : {std::string(), kWrongToken}) {
      bool closed = false;
      auto answer = HelloAnswer(hop.server.port, hop.role, hop.hash, bad, &closed);
      ASSERT_TRUE(answer.ok()) << answer.error().message;
      ASSERT_TRUE(answer->has_error()) << "refused, not " << BodyName(*answer);
      EXPECT_EQ(answer->error().code(), wire::ERROR_CODE_AUTH_FAILED);
      EXPECT_TRUE(answer->error().fatal());
      EXPECT_TRUE(Contains(answer->error().message(), "authentication failed")) << answer->error().message();
      EXPECT_FALSE(Contains(answer->error().message(), hop.token)) << "the message never holds the token";
      EXPECT_TRUE(closed) << "the server closes after AUTH_FAILED";
    }
    auto welcomed = HelloAnswer(hop.server.port, hop.role, hop.hash, hop.token, nullptr);
    ASSERT_TRUE(welcomed.ok()) << welcomed.error().message;
    EXPECT_TRUE(welcomed->has_welcome()) << BodyName(*welcomed) << ": "
                                         << (welcomed->has_error() ? welcomed->error().message() : "");
  }
  // The SMA presented the renderer's token: its renderer is connected.
  EXPECT_TRUE(WaitUntil([&] { return Counter(sma, "renderers_connected", kClientToken) == 1.0; }, 20s)) << sma.process.LogTail();
  for (Service* s : {&renderer, &sma}) {
    EXPECT_TRUE(s->process.Running()) << s->process.LogTail();
    const std::string log = ReadWhole(s->process.LogPath());
    EXPECT_TRUE(Contains(log, "authentication failed")) << "refusals are logged";
    for (const std::string& token : {kRendererToken, kClientToken, kWrongToken})
      EXPECT_FALSE(Contains(log, token)) << "a token in the log:\n" << log;
  }
}

// SMA -> renderer with real SMAs: without the token and with a wrong one the
// SMA says at error level that the renderer refused it, and gets no renderer;
// with the right one on both hops the headless client renders the box. A
// client without the right token fails fast (no endless retry) with the
// SMA's reason.
TEST_F(SecurityTest, TokensOnBothHopsServeTheRightPeersOnly) {
  Service renderer = StartRenderer({"--auth-token-file", *rendererTokenFile_}, "stack");
  {
    Service noToken = StartSma(renderer.Address(), {}, "no-renderer-token");
    Service wrongToken = StartSma(renderer.Address(), {"--renderer-auth-token-file", *wrongTokenFile_}, "wrong");
    for (Service* sma : {&noToken, &wrongToken}) {
      EXPECT_TRUE(WaitForLog(sma->process, "refused this SMA")) << sma->process.LogTail();
      EXPECT_TRUE(Contains(ReadWhole(sma->process.LogPath()), "AUTH_FAILED"));
      EXPECT_EQ(Counter(*sma, "renderers_connected"), 0.0);
      EXPECT_TRUE(sma->process.Running()) << "an SMA stays up, retrying slowly";
    }
  }
  Service sma = StartSma(renderer.Address(),
                         {"--auth-token-file", *clientTokenFile_, "--renderer-auth-token-file", *rendererTokenFile_},
                         "right");
  std::string log;
  auto code = RunClient(sma.Address(), {"--auth-token-file", *clientTokenFile_}, "token-right", &log);
  ASSERT_EQ(code, std::optional<int>(0)) << log << sma.process.LogTail();
  ExpectLitImage("token-right");

  for (const auto& [tag, extra] : std::vector<std::pair<std::string, std::vector<std::string>>>{
           {"token-none", {"--connect-timeout", "120"}},
           {"token-wrong", {"--auth-token-file", *wrongTokenFile_, "--connect-timeout", "120"}}}) {
    SCOPED_TRACE(tag);
    const auto started = Clock::now();
    // A connect timeout far above what a refusal takes (even on a loaded
    // machine): failing fast is the point.
    code = RunClient(sma.Address(), extra, tag, &log, 150s);
    ASSERT_EQ(code, std::optional<int>(1)) << log;
    EXPECT_LT(Clock::now() - started, 60s) << "a refusal is final: no retrying until the connect timeout";
    EXPECT_TRUE(Contains(log, "AUTH_FAILED")) << log;
    EXPECT_TRUE(Contains(log, "authentication failed")) << log;
    EXPECT_FALSE(Contains(log, kClientToken));
  }
  EXPECT_TRUE(sma.process.Running()) << sma.process.LogTail();
}

// TLS on both hops with the right CA: the stack converges.
TEST_F(SecurityTest, TlsOnBothHopsWithTheRightCaServes) {
  Service renderer = StartRenderer({"--tls-cert", pki_->cert, "--tls-key", pki_->key}, "tls");
  Service sma = StartSma(renderer.Address(),
                         {"--renderer-tls-ca", pki_->ca, "--tls-cert", pki_->cert, "--tls-key", pki_->key}, "tls");
  EXPECT_TRUE(WaitForLog(sma.process, "ready")) << sma.process.LogTail();
  std::string log;
  auto code = RunClient(sma.Address(), {"--tls-ca", pki_->ca}, "tls-right", &log);
  ASSERT_EQ(code, std::optional<int>(0)) << log << sma.process.LogTail() << renderer.process.LogTail();
  ExpectLitImage("tls-right");
  EXPECT_TRUE(Contains(ReadWhole(sma.process.LogPath()), "(TLS")) << "the SMA says it listens with TLS";
}

// TLS with a CA that did not issue the server's certificate, or a certificate
// for another name: refused on both hops, with the reason.
TEST_F(SecurityTest, TlsWithTheWrongCaOrNameIsRefused) {
  Service renderer = StartRenderer({"--tls-cert", pki_->cert, "--tls-key", pki_->key}, "tls-ca");
  {
    Service sma = StartSma(renderer.Address(), {"--renderer-tls-ca", pki_->otherCa}, "wrong-ca");
    EXPECT_TRUE(WaitForLog(sma.process, "certificate verify failed")) << sma.process.LogTail();
    EXPECT_EQ(Counter(sma, "renderers_connected"), 0.0);
    EXPECT_TRUE(WaitForLog(renderer.process, "TLS handshake failed")) << renderer.process.LogTail();
  }
  Service sma = StartSma(renderer.Address(),
                         {"--renderer-tls-ca", pki_->ca, "--tls-cert", pki_->cert, "--tls-key", pki_->key}, "ca");
  // A refused certificate is final for a client: it stops at the first
  // attempt, well before its connect timeout, and says why.
  std::string log;
  auto started = Clock::now();
  auto code = RunClient(sma.Address(), {"--tls-ca", pki_->otherCa, "--connect-timeout", "60"}, "tls-wrong-ca", &log);
  ASSERT_EQ(code, std::optional<int>(1)) << log;
  EXPECT_LT(Clock::now() - started, 30s) << "a refused certificate is final: no retrying until the connect timeout";
  EXPECT_TRUE(Contains(log, "certificate verify failed")) << log;
  EXPECT_TRUE(Contains(log, "not retrying")) << log;

  Service misnamed = StartSma(renderer.Address(),
                              {"--renderer-tls-ca", pki_->ca, "--tls-cert", pki_->wrongNameCert, "--tls-key",
                               pki_->wrongNameKey},
                              "misnamed");
  started = Clock::now();
  code = RunClient(misnamed.Address(), {"--tls-ca", pki_->ca, "--connect-timeout", "60"}, "tls-wrong-name", &log);
  ASSERT_EQ(code, std::optional<int>(1)) << log;
  EXPECT_LT(Clock::now() - started, 30s) << "a certificate for another name is final too";
  EXPECT_TRUE(Contains(log, "hostname mismatch")) << "host name verification against 127.0.0.1:\n" << log;
  EXPECT_TRUE(renderer.process.Running());
}

// A plain peer at a TLS server and a TLS peer at a plain server get a clear
// error, not a hang; a peer that never completes the TLS handshake is dropped.
TEST_F(SecurityTest, PlainAndTlsPeersThatMeetGetAClearError) {
  Service renderer = StartRenderer({"--tls-cert", pki_->cert, "--tls-key", pki_->key, "--handshake-timeout-ms", "500"},
                                   "mixed");
  bool closed = false;
  auto answer = HelloAnswer(renderer.port, wire::ROLE_SMA, sceneHash_, "", &closed);
  ASSERT_TRUE(answer.ok()) << answer.error().message;
  ASSERT_TRUE(answer->has_error()) << BodyName(*answer);
  EXPECT_EQ(answer->error().code(), wire::ERROR_CODE_AUTH_FAILED);
  EXPECT_TRUE(Contains(answer->error().message(), "TLS connections only")) << answer->error().message();
  EXPECT_TRUE(closed);

  auto silent = WireClient::Connect("127.0.0.1", renderer.port);
  ASSERT_TRUE(silent.ok());
  EXPECT_TRUE(silent->WaitClosed(5s)) << "a peer that never starts the TLS handshake is dropped";
  EXPECT_TRUE(WaitForLog(renderer.process, "TLS handshake not completed within 500 ms")) << renderer.process.LogTail();

  // A plain client at a TLS SMA: refused for good, at once.
  Service tlsSma = StartSma(renderer.Address(),
                            {"--renderer-tls-ca", pki_->ca, "--tls-cert", pki_->cert, "--tls-key", pki_->key}, "mixed");
  std::string log;
  const auto started = Clock::now();
  auto code = RunClient(tlsSma.Address(), {"--connect-timeout", "120"}, "plain-to-tls", &log, 150s);
  ASSERT_EQ(code, std::optional<int>(1)) << log;
  EXPECT_LT(Clock::now() - started, 60s) << "a refusal is final: no retrying until the connect timeout";
  EXPECT_TRUE(Contains(log, "TLS connections only")) << log;

  // A TLS client at a plain SMA.
  Service plainSma = StartSma(renderer.Address(), {"--renderer-tls-ca", pki_->ca}, "plain");
  code = RunClient(plainSma.Address(), {"--tls-ca", pki_->ca, "--connect-timeout", "6"}, "tls-to-plain", &log);
  ASSERT_EQ(code, std::optional<int>(1)) << log;
  EXPECT_TRUE(Contains(log, "TLS handshake failed")) << log;
  EXPECT_TRUE(WaitForLog(plainSma.process, "listens in plain TCP")) << plainSma.process.LogTail();
  EXPECT_TRUE(renderer.process.Running());
}

// Wrong security files stop a process at start-up with one clear line (exit
// 2) before it loads the scene; a token file others may read draws a warning.
TEST_F(SecurityTest, BadTokenAndCertificateFilesStopTheProcessAtStartUp) {
  const std::string empty = WriteToken(*dir_, "empty.token", "");
  const std::string missing = *dir_ + "/missing.token";
  struct Case {
    std::string exe;
    std::vector<std::string> args;
    std::string expected;
  };
  const std::string renderer = PENUMBRA_RENDERER_EXE, sma = PENUMBRA_SMA_EXE, client = PENUMBRA_CLIENT_EXE;
  const std::vector<std::string> rendererBase = {"--scene", kScene, "--listen", "127.0.0.1:0"};
  const std::vector<std::string> smaBase = {"--scene", kScene, "--listen", "127.0.0.1:0", "--renderer", "127.0.0.1:9"};
  const std::vector<std::string> clientBase = {"--connect", "127.0.0.1:9", "--headless", "--gl", "egl"};
  const auto with = [](std::vector<std::string> base, const std::vector<std::string>& more) {
    base.insert(base.end(), more.begin(), more.end());
    return base;
  };
  const std::vector<Case> cases = {
      {renderer, with(rendererBase, {"--auth-token-file", empty}), "holds no token"},
      {renderer, with(rendererBase, {"--auth-token-file", missing}), "missing.token"},
      {renderer, with(rendererBase, {"--tls-cert", pki_->cert, "--tls-key", pki_->wrongNameKey}),
       "is not the key of the certificate"},
      {renderer, with(rendererBase, {"--tls-cert", pki_->key, "--tls-key", pki_->key}), "not a PEM certificate chain"},
      {sma, with(smaBase, {"--renderer-auth-token-file", empty}), "--renderer-auth-token-file"},
      {sma, with(smaBase, {"--renderer-tls-ca", missing}), "missing.token"},
      {client, with(clientBase, {"--auth-token-file", missing}), "--auth-token-file"},
      {client, with(clientBase, {"--tls-ca", pki_->key}), "no PEM CA certificate"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    SCOPED_TRACE(c.expected);
    auto process = ChildProcess::Spawn(c.exe, c.args, fmt::format("{}/startup-{}.log", *dir_, i));
    ASSERT_TRUE(process.ok()) << process.error().message;
    const auto code = process->WaitExit(30s);
    const std::string log = ReadWhole(process->LogPath());
    EXPECT_EQ(code, std::optional<int>(2)) << log;
    EXPECT_TRUE(Contains(log, c.expected)) << log;
  }

  const std::string shared = *dir_ + "/shared.token";
  std::ofstream(shared) << kRendererToken << "\n";
  ::chmod(shared.c_str(), 0644);
  Service open = StartRenderer({"--auth-token-file", shared}, "shared-token");
  const std::string log = ReadWhole(open.process.LogPath());
  EXPECT_TRUE(Contains(log, "chmod 600")) << log;
  EXPECT_FALSE(Contains(log, kRendererToken)) << log;
}

}  // namespace
}  // namespace penumbra::testing
